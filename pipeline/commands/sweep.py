"""`sonarmap sweep`: datasets x override values, locally or on Ray."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    NO_FIGURES_OPT,
    STORE_OPT,
    cli_graph,
    emit_json,
)

__all__ = ["register", "sweep", "units_reused"]

if TYPE_CHECKING:
    from sonarmap.pipeline.experiments.sweep import RunOutcome


def units_reused(stages: Sequence[Mapping[str, Any]]) -> str:
    """What a run's stages reused of the per-keyframe work units already in the store, as
    "; units reused: features 120/130, classify 0/130" ("" when no stage computed any)."""
    parts = []
    for s in stages:
        units = s.get("units")
        if units:
            reused, computed = units
            parts.append(f"{s.get('stage')} {reused}/{reused + computed}")
    return f"; units reused: {', '.join(parts)}" if parts else ""


def sweep(
    ctx: typer.Context,
    datasets: list[Path] = typer.Argument(..., help="Recordings to sweep over."),
    set_: list[str] | None = typer.Option(
        None, "--set", "-s", help="Swept values: section.field=v1,v2 (cross product)."
    ),
    fixed: list[str] | None = typer.Option(
        None, "--fix", help="Fixed override for every run: section.field=value."
    ),
    config: Path | None = CONFIG_OPT,
    executor: str = typer.Option("local", "--executor", help="local (process pool) or ray."),
    jobs: int = typer.Option(1, "--jobs", "-j", help="Parallel runs."),
    address: str | None = typer.Option(None, "--address", help="Ray cluster address."),
    out: Path | None = typer.Option(
        None, "--out", help="Results folder (default data/sweeps/<id>)."
    ),
    store: Path = STORE_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Run the cross product of DATASETS and --set values; write a mean/std table and plot.

    Every dataset and config point is checked before the first run; the --config file is
    read once (a copy goes into the results folder). Exits non-zero
    when any run failed (2: bad input, 1: a bug), after the others have finished and
    the tables are written.
    """
    import hashlib
    import os
    import signal

    from sonarmap.pipeline.commands._errors import check_writable, display_path, one_line
    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.pipeline.experiments.sweep import expand, run_sweep
    from sonarmap.pipeline.experiments.sweep_checks import check_inputs, failure_exit_code
    from sonarmap.pipeline.experiments.sweep_output import write_sweep

    if jobs < 1:
        raise ConfigError(f"--jobs {jobs}: at least 1 run at a time")
    if executor not in ("local", "ray"):
        raise ConfigError(f"--executor {executor}: expected 'local' or 'ray'")
    from dataclasses import replace
    from functools import partial

    from sonarmap.pipeline.commands._config_references import check_references
    from sonarmap.pipeline.engine.config.load import config_model_for, is_list_key

    graph = cli_graph(ctx)
    model = config_model_for(graph.config_stages, graph.extra_sections)
    specs = expand(
        datasets,
        set_ or (),
        base_overrides=fixed or (),
        config_path=config,
        store=store,
        is_list_key=partial(is_list_key, model),
        figures=not no_figures,
    )
    # Every dataset and every point's config before the first run: a missing file or
    # a bad value fails now, not hours in.
    check_inputs(specs, graph, check_references)
    # The config file is read once: every point maps with the text checked here, kept in
    # the results folder (edited during a sweep, it changed the later points' settings).
    text = config.read_bytes() if config is not None else b""
    ident = hashlib.sha256(
        repr([(s.dataset, s.overrides) for s in specs] + [fixed or [], text]).encode()
    ).hexdigest()
    out_dir = out or Path("data/sweeps") / ident[:12]
    check_writable(out_dir)
    if config is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        kept = out_dir / "config.yaml"
        kept.write_bytes(text)
        specs = [replace(s, config_path=str(kept.resolve())) for s in specs]
    if executor == "local":
        # One process per parallel run, each with its own memory (a run of the demo peaks
        # at about 0.7 GB): never more than there are runs, and said when over the cores.
        jobs = min(jobs, len(specs))
        cores = os.cpu_count() or 1
        if jobs > cores:
            typer.echo(
                f"warning: sweep: {jobs} runs at a time on {cores} cores; each takes its own"
                " memory, and they share the cores",
                err=True,
            )
    typer.echo(f"sweep: {len(specs)} runs on {executor} with {jobs} job(s)", err=True)

    def describe(o: RunOutcome) -> str:
        overrides = ", ".join(f"{k}={v}" for k, v in o.overrides.items()) or "(defaults)"
        return f"{display_path(o.dataset)} [{overrides}]"

    finished: list[RunOutcome] = []

    def done(o: RunOutcome) -> None:
        # Plain lines (not a rich console): a log file or CI keeps each on one line.
        tail = f": {o.error}" if o.error else units_reused(o.stages)
        typer.echo(one_line(f"{o.status} {describe(o)} {o.seconds:.1f} s{tail}"), err=True)
        finished.append(o)

    from sonarmap.pipeline.commands._errors import writes_under

    with writes_under(store, out_dir):
        try:
            outcomes = run_sweep(
                specs, executor=executor, jobs=jobs, address=address, on_done=done, graph=graph
            )
        except (KeyboardInterrupt, SystemExit) as stop:
            status = 130 if isinstance(stop, KeyboardInterrupt) else stop.code
            if status not in (130, 128 + signal.SIGTERM, 128 + signal.SIGHUP):
                raise
            # The finished points' rows are written; a rerun takes them from the store.
            if finished:
                write_sweep(finished, out_dir)
            typer.echo(
                f"sweep: interrupted after {len(finished)} of {len(specs)} runs"
                + (f"; their table in {out_dir}" if finished else "")
                + " (a rerun reuses what they computed)",
                err=True,
            )
            raise typer.Exit(status) from None
        doc = write_sweep(outcomes, out_dir)
        if json_:
            emit_json(doc)
        else:
            typer.echo((out_dir / "table.md").read_text())
            typer.echo(f"results: {out_dir}")
    failed = [o for o in outcomes if o.status != "ok"]
    for o in failed:
        typer.echo(one_line(f"failed: {describe(o)}: {o.error}"), err=True)
    code = failure_exit_code(outcomes)
    if code:
        typer.echo(
            one_line(
                f"error: {len(failed)} of {len(outcomes)} sweep runs failed, first "
                f"{describe(failed[0])}: {failed[0].error} (results in {out_dir})"
            ),
            err=True,
        )
        raise typer.Exit(code)


def register(app: typer.Typer) -> None:
    app.command("sweep")(sweep)
