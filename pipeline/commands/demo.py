"""`sonarmap demo`: simulate the default marina, train if needed, run every stage, report."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    NO_FIGURES_OPT,
    SET_OPT,
    STORE_OPT,
    WORKERS_OPT,
    cli_graph,
    emit_json,
)
from sonarmap.pipeline.commands.simulate import DEFAULT_SENSORS, SONAR_OPTS

__all__ = ["demo", "register"]


def _stage_section(result: Any) -> str:
    """Markdown of the run's stages: key, status now, and the compute time of the artifact.

    The evaluate stage cannot see this (its key must not depend on timings), so the
    demo appends it to its copy of the report.
    """
    lines = [
        "",
        "## Stages",
        "",
        "| stage | key | this run | compute time s |",
        "|---|---|---|---:|",
    ]
    for r in result.stages:
        built = result.artifacts[r.stage].manifest.get("build_seconds")
        lines.append(f"| {r.stage} | `{r.key[:16]}` | {r.status} | {built} |")
    return "\n".join(lines) + "\n"


def _figures_section(names: Sequence[str], skipped: bool) -> str:
    """Markdown of the figures copied beside the report (the figure stages' PNGs)."""
    if skipped:
        return "\n## Figures\n\nNot drawn (`--no-figures`).\n"
    if not names:
        return ""
    links = [f"![{n.rsplit('.', 1)[0]}]({n})" for n in names]
    return "\n".join(["", "## Figures", "", *links, ""])


def _write_report(report_dir: Path, result: Any, no_figures: bool) -> Path:
    """report/: evaluate's files and the figure stages' PNGs, the report with its figures
    and the run's stages appended (evaluate's report cannot know either)."""
    import shutil

    from sonarmap.pipeline.graph import FIGURE_STAGES

    shutil.rmtree(report_dir, ignore_errors=True)
    report_dir.mkdir(parents=True)
    figures: list[str] = []
    for stage in ("evaluate", *FIGURE_STAGES):
        ref = result.artifacts.get(stage)
        for name in () if ref is None else ref.manifest.get("files", {}):
            shutil.copyfile(ref.file(name), report_dir / Path(name).name)
            figures += [Path(name).name] if stage in FIGURE_STAGES else []
    with (report_dir / "report.md").open("a") as report:
        report.write(_figures_section(figures, no_figures))
        report.write(_stage_section(result))
    return report_dir / "report.md"


def _training_simulations(config: Path | None, overrides: Sequence[str], store: Path) -> list[Any]:
    """The default classifier's simulated missions under this config, so the demo can
    simulate them beside the mapped scene instead of after it; none when the model is
    at hand (the run's store, the model cache, or shipped with the project)."""
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
    from sonarmap.pipeline.graph import all_stages, extra_sections
    from sonarmap.pipeline.readers.referenced_files import pin_referenced_files
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.model import training_simulations
    from sonarmap.pipeline.training.model_cache import planned_default_model

    resolved = pin_referenced_files(load_config(all_stages(), config, overrides, extra_sections()))
    if planned_default_model(ArtifactStore(store), resolved)[1]:
        return []
    return training_simulations(getattr(resolved, "training", TrainingDataConfig()))


DEMO_SENSORS: dict[str, str] | None = DEFAULT_SENSORS
"""The demo recording's sensors when no `--sonar` names one (`simulate`'s default, the
Oculus pair; part of the recording's recipe; None would be the clean sensor with the
recipe as before sensors had names)."""


def _sensors(both: str | None, horizontal: str | None, vertical: str | None) -> Any:
    """The demo recording's sensors (part of its recipe), or None for the clean default."""
    from sonarmap.pipeline.training.sim_sensors import chosen_sensors

    if not (both or horizontal or vertical or DEMO_SENSORS):
        return None
    return chosen_sensors(both, horizontal, vertical, DEMO_SENSORS or DEFAULT_SENSORS)


def demo(
    ctx: typer.Context,
    out: Path = typer.Option(Path("data/demo"), "--out", help="Where the dataset and report go."),
    scene: str = typer.Option("marina", "--scene", help="Scene name or YAML path."),
    seed: int = typer.Option(0, "--seed", min=0, help="Simulation seed."),
    goals: int | None = typer.Option(
        None, "--goals", min=1, max=1000, help="Mission goals (default 20)."
    ),
    duration_s: float | None = typer.Option(None, "--duration-s", help="Cut the mission short."),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    store: Path = STORE_OPT,
    workers: int | None = WORKERS_OPT,
    no_figures: bool = NO_FIGURES_OPT,
    json_: bool = JSON_OPT,
    sonar: str | None = SONAR_OPTS["sonar"],
    horizontal_sonar: str | None = SONAR_OPTS["horizontal"],
    vertical_sonar: str | None = SONAR_OPTS["vertical"],
) -> None:
    """The whole pipeline on a simulated marina, ending with the coverage table and report."""
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.commands._common import stderr_console
    from sonarmap.pipeline.commands._errors import writes_under
    from sonarmap.pipeline.engine.run.progress import StageProgress
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    with writes_under(out, store):
        console = stderr_console()
        scene_file = scene_path(scene)
        dataset = out / f"{scene_file.stem}-seed{seed}.mcap"
        console.print(f"dataset: {dataset}")
        sonars = _sensors(sonar, horizontal_sonar, vertical_sonar)
        mapped = Simulation(scene_file, seed, dataset, goals, duration_s, sonars=sonars)
        if sonars is not None:
            console.print(f"sensors: {', '.join(f'{s} {n}' for s, n in sonars.items())}")
        ensure_simulations(
            [mapped, *_training_simulations(config, set_ or (), store)], os.cpu_count() or 1
        )
        with StageProgress(enabled=True) as progress:
            result, summary = run_dataset(
                RunRequest(
                    dataset,
                    config_path=config,
                    overrides=set_ or (),
                    store_dir=store,
                    workers=workers,
                    figures=not no_figures,
                ),
                cli_graph(ctx),
                on_start=progress.on_start,
                on_stage=progress.on_stage,
                scores=json_,
            )
        evaluate = result.artifacts.get("evaluate")
        if evaluate is not None:
            summary["report"] = str(_write_report(out / "report", result, no_figures))
        from sonarmap.pipeline.report_cli import front_end_of

        front_end = front_end_of(result)
        if json_:
            emit_json({**result.to_json(), "summary": {**summary, **front_end}})
            return
        from sonarmap.pipeline.report_cli import (
            front_end_lines,
            print_summary,
            progress_shares_stdout,
        )

        print_summary(result, summary, stages_listed=progress_shares_stdout())
        for line in front_end_lines(front_end):
            typer.echo(line)


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)
