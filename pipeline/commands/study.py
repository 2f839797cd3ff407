"""`sonarmap study`: the paper's simulation study (Table I and Fig. 4 analogues) in one command."""

from __future__ import annotations

from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import (
    JSON_OPT,
    NO_FIGURES_OPT,
    STORE_OPT,
    cli_graph,
    emit_json,
)

__all__ = ["register", "study"]


def _protocols(configs: list[Path], with_default: bool) -> list[dict[str, str | None]]:
    """[{"name", "config"}]: the defaults (unless left out), then each file by its stem."""
    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.pipeline.experiments.study_tables import DEFAULT_PROTOCOL

    protocols: list[dict[str, str | None]] = (
        [{"name": DEFAULT_PROTOCOL, "config": None}] if with_default else []
    )
    for path in configs:
        if not path.is_file():
            raise ConfigError(f"--config {path}: no such file")
        taken = [p for p in protocols if p["name"] == path.stem]
        if taken:
            other = taken[0]["config"] or "sonarmap's defaults"
            raise ConfigError(
                f"--config {path}: protocol name '{path.stem}' is already taken by {other} "
                "(protocols are named by the file stem; rename one)"
            )
        protocols.append({"name": path.stem, "config": str(path)})
    if not protocols:
        raise ConfigError("--no-default needs at least one --config FILE")
    return protocols


def _spacings(spacings: str, swept: str, base: list[str]) -> list[str]:
    """The swept spacings, refused (naming --spacings or --fix) before any simulation: a
    list `sweep` would refuse (empty, a value twice, also fixed), or a --fix of the poses
    (the study maps with true poses: its tables say so)."""
    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.pipeline.experiments.sweep_grid import sweep_axes

    for text in base[1:]:
        if text.partition("=")[0].strip() == "slam.mode":
            raise ConfigError(
                f"--fix '{text}': the study maps with true poses (slam.mode=ground_truth, as"
                " the paper's); map other poses with `sonarmap sweep`"
            )
    try:
        sweep_axes([], [swept], base)
    except ConfigError as err:
        raise ConfigError(
            str(err).replace(f"--set '{swept}'", f"--spacings '{spacings}'")
        ) from None
    return [v.strip() for v in spacings.split(",") if v.strip()]


def study(
    ctx: typer.Context,
    trials: int = typer.Option(10, "--trials", min=1, help="Simulated trials (seeds 0..N-1)."),
    goals: int = typer.Option(20, "--goals", min=1, max=1000, help="Random goals per trial."),
    duration_s: float | None = typer.Option(
        None,
        "--duration-s",
        min=1.0,
        help="Cut each mission after S seconds (default: all goals).",
    ),
    scene: str = typer.Option("marina", "--scene", help="Scene name or YAML path."),
    spacings: str = typer.Option(
        "2,4", "--spacings", help="Keyframe spacings in metres, comma-separated."
    ),
    configs: list[Path] | None = typer.Option(
        None,
        "--config",
        "-c",
        help="A protocol to compare: pipeline config YAML, named by its stem. Repeatable.",
    ),
    no_default: bool = typer.Option(
        False, "--no-default", help="Leave out the protocol of sonarmap's own defaults."
    ),
    fixed: list[str] | None = typer.Option(
        None, "--fix", help="Override for every protocol's runs: section.field=value."
    ),
    executor: str = typer.Option("local", "--executor", help="local or ray."),
    jobs: int = typer.Option(1, "--jobs", "-j", min=1, help="Parallel runs (at most one per run)."),
    address: str | None = typer.Option(None, "--address", help="Ray cluster address."),
    out: Path = typer.Option(Path("data/study"), "--out", help="Datasets and results folder."),
    store: Path = STORE_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """The paper's simulation study: Table I beside the paper's, and Fig. 4.

    Simulates N trials and maps each, with true poses, at every spacing under every
    protocol (the defaults and each --config); writes Table I with the per-class accounting
    to OUT/results/table_i.md and Fig. 4 to OUT/results/fig4_errors.png."""
    import time

    from sonarmap.pipeline.commands._common import stderr_console
    from sonarmap.pipeline.commands._errors import check_writable, one_line, writes_under
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.experiments.study import write_study
    from sonarmap.pipeline.experiments.sweep import expand, run_sweep
    from sonarmap.pipeline.experiments.sweep_checks import failure_exit_code
    from sonarmap.pipeline.training.datasets import ensure_simulation, scene_path

    check_writable(out)
    graph = cli_graph(ctx)
    with writes_under(out, store):
        console = stderr_console()
        t0 = time.perf_counter()
        protocols = _protocols(configs or [], not no_default)
        base = ["slam.mode=ground_truth", *(fixed or ())]
        swept = f"keyframes.spacing_m={spacings}"
        values = _spacings(spacings, swept, base)
        for p in protocols:  # a typo fails now, not in every run
            config = Path(p["config"]) if p["config"] else None
            for v in values:
                overrides = [*base, f"keyframes.spacing_m={v}"]
                load_config(graph.config_stages, config, overrides, graph.extra_sections)
            if config is not None:  # read once: every run maps with the text checked here
                kept = out / "results" / "protocols" / config.name
                kept.parent.mkdir(parents=True, exist_ok=True)
                kept.write_bytes(config.read_bytes())
                p["config"] = str(kept.resolve())
        scene_file = scene_path(scene)
        datasets = []
        for seed in range(trials):
            cut = "" if duration_s is None else f"-{duration_s:g}s"
            path = out / f"{scene_file.stem}-goals{goals}{cut}-seed{seed}.mcap"
            console.print(f"trial {seed}: {path}")
            datasets.append(
                ensure_simulation(scene_file, seed, path, goals=goals, duration_s=duration_s)
            )
        specs = [
            spec
            for p in protocols
            for spec in expand(
                datasets,
                [swept],
                base_overrides=base,
                config_path=Path(p["config"]) if p["config"] else None,
                store=store,
                protocol=p["name"],
                figures=not no_figures,
            )
        ]
        jobs = min(jobs, len(specs))  # one process per parallel run, never more than runs
        console.print(
            f"study: {len(specs)} runs ({len(protocols)} protocol(s) x {trials} trial(s) x "
            f"{len(values)} spacing(s)) on {executor} with {jobs} job(s)"
        )
        outcomes = run_sweep(
            specs,
            graph=graph,
            executor=executor,
            jobs=jobs,
            address=address,
            on_done=lambda o: typer.echo(  # plain lines: a log file keeps each on one line
                one_line(
                    f"{o.status} {o.protocol}: {Path(o.dataset).name} {o.overrides} "
                    f"{o.seconds:.1f} s {o.error or ''}"
                ),
                err=True,
            ),
        )
        header = [
            "Protocols: "
            + ", ".join(f"{p['name']} ({p['config'] or 'sonarmap defaults'})" for p in protocols)
            + ".",
            f"Trials: {trials} (seeds 0..{trials - 1}) of scene {scene_file.stem}, {goals} goals"
            + ("" if duration_s is None else f", cut at {duration_s:g} s")
            + f"; spacings {', '.join(values)} m; overrides: {', '.join(base)}.",
        ]
        doc = write_study(outcomes, out / "results", protocols=protocols, header=header, started=t0)
        if json_:
            emit_json(doc)
        else:
            typer.echo(doc["table_i"])
            typer.echo(f"wall time {doc['wall_s']} s; results in {out / 'results'}")
        failed = [o for o in outcomes if o.status != "ok"]
        for o in failed:
            typer.echo(one_line(f"failed: {o.protocol}: {o.dataset}: {o.error}"), err=True)
        code = failure_exit_code(outcomes)  # as `sweep`: 2 bad input, 1 a bug
        if code:
            typer.echo(
                one_line(
                    f"error: {len(failed)} of {len(outcomes)} study runs failed, first"
                    f" {failed[0].protocol}: {failed[0].error} (results in {out / 'results'})"
                ),
                err=True,
            )
            raise typer.Exit(code)


def register(app: typer.Typer) -> None:
    app.command("study")(study)
