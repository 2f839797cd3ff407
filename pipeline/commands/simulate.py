"""`sonarmap simulate`: simulate an orthogonal sonar pair in a scene and write a ROS 2 MCAP."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.training.sim_sensors import OCULUS_PAIR

__all__ = ["DEFAULT_SCENE", "DEFAULT_SENSORS", "SONAR_OPTS", "register"]

DEFAULT_SCENE = "marina"
"""A scene name in configs/scenes/ (the help shows the name, not the install path)."""

DEFAULT_SENSORS = dict(OCULUS_PAIR)
"""The sensors a simulation gets when no `--sonar` names one: the README vehicle's Oculus
pair's image character (`--sonar sim-clean`: the simulator's clean sensor)."""

SONAR_OPTS = {
    "sonar": typer.Option(
        None,
        "--sonar",
        help="Sensor of both sonars: a preset of configs/sonars/ with an image block"
        " (its image character; the sim geometry is kept) or sim-clean.",
    ),
    "horizontal": typer.Option(
        None, "--horizontal-sonar", help="Sensor of the horizontal sonar (wins over --sonar)."
    ),
    "vertical": typer.Option(
        None, "--vertical-sonar", help="Sensor of the vertical sonar (wins over --sonar)."
    ),
}
"""The sensor options of `simulate` and `demo`."""


def simulate_cmd(
    output: Path = typer.Option(..., "--output", "-o", help="Output .mcap path."),
    scene_name: str = typer.Option(
        DEFAULT_SCENE, "--scene", help="Scene name in configs/scenes/, or a scene YAML path."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed (same seed, same bytes)."),
    goals: int | None = typer.Option(
        None, "--goals", min=1, max=1000, help="Number of mission goals."
    ),
    duration_s: float | None = typer.Option(
        None, "--duration-s", min=0.001, help="Cut the mission after this many seconds."
    ),
    preview: Path | None = typer.Option(
        None, "--preview", help="Also write a PNG of one horizontal and one vertical ping."
    ),
    workers: int = typer.Option(
        1,
        "--workers",
        "-j",
        min=1,
        max=64,
        help="Processes rendering pings (same bytes for any number; 1: in this process).",
    ),
    sonar: str | None = SONAR_OPTS["sonar"],
    horizontal_sonar: str | None = SONAR_OPTS["horizontal"],
    vertical_sonar: str | None = SONAR_OPTS["vertical"],
    settings: list[str] | None = typer.Option(
        None,
        "--set",
        "-s",
        help="Simulator setting KEY=VALUE (repeatable; after the sensors), e.g."
        " horizontal.noise_mean_level=53 or mission.speed_m_s=0.3.",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    config_path: Path | None = typer.Option(
        None,
        "--config",
        "-c",
        help="Pipeline config YAML whose class table (section `classes`) the scene's classes"
        " come from (default: the default table).",
    ),
) -> None:
    """Simulate a mission (scene, seed) and write it as a ROS 2 MCAP dataset with ground truth."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from sonarmap.pipeline.commands._common import stderr_console
    from sonarmap.pipeline.engine.errors import ConfigError, SourceError
    from sonarmap.pipeline.formats.atomic import atomic_output
    from sonarmap.pipeline.formats.sim_preview import render_preview
    from sonarmap.pipeline.formats.simulation import write_simulation
    from sonarmap.pipeline.training.datasets import read_scene, scene_path, sim_config
    from sonarmap.pipeline.training.sim_sensors import chosen_sensors, with_settings
    from sonarmap.sim.dataset import simulate

    sonars = chosen_sensors(sonar, horizontal_sonar, vertical_sonar, DEFAULT_SENSORS)

    scene = scene_path(scene_name)
    scene_obj = read_scene(scene)
    from sonarmap.pipeline.engine.config.yaml_files import CONFIG_MAX_BYTES
    from sonarmap.pipeline.engine.user_files import read_user_file

    # The same guarded read as the scene's parse (a regular file, capped): copied as is.
    scene_text = read_user_file(scene, "scene", ConfigError, CONFIG_MAX_BYTES).decode()
    if output.parent.exists() and not output.parent.is_dir():
        raise SourceError(f"output directory {output.parent} is not a directory")
    from sonarmap.pipeline.formats.atomic import check_output_path

    for path in (output, preview):  # before any work: a FIFO, a device or a folder
        if path is not None:
            check_output_path(path, [scene])
    if duration_s is not None and not math.isfinite(duration_s):
        raise ConfigError(f"--duration-s {duration_s}: not a finite number of seconds")
    config = with_settings(sim_config(goals, duration_s, sonars=sonars), settings or ())
    table = _class_table(config_path)
    try:
        run = simulate(scene_obj, config, seed, table)
    except ValueError as err:
        raise ConfigError(f"scene {scene}: {err}") from err
    console = stderr_console()
    given = {"horizontal": sonar or horizontal_sonar, "vertical": sonar or vertical_sonar}
    named = ", ".join(f"{s} {n}{'' if given[s] else ' (default)'}" for s, n in sonars.items())
    console.print(f"sensors: {named}" + (f"; set {', '.join(settings)}" if settings else ""))
    with Progress(
        TextColumn("simulate"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} frames"),
        TimeRemainingColumn(),
        console=console,
        disable=quiet,
        transient=False,
    ) as bar:
        task = bar.add_task("frames", total=run.n_frames)
        info = write_simulation(
            run,
            output,
            scene_yaml=scene_text,
            progress=lambda done, _n: bar.update(task, completed=done),
            workers=workers,
        )
    if preview is not None:
        try:
            preview.parent.mkdir(parents=True, exist_ok=True)
            png = render_preview(run)
            with atomic_output(preview) as f:
                f.write(png)
        except OSError as err:
            raise SourceError(f"cannot write preview {preview}: {err}") from err
    console.print(
        f"wrote {info['path']}: {info['n_frames']} frames, {info['bytes'] / 1e6:.1f} MB, "
        f"{info['frames_per_s']:.1f} frames/s"
    )


def _class_table(path: Path | None) -> Any:
    """The class table of the pipeline config at `path` (the default table for None)."""
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.graph import default_graph
    from sonarmap.schemas.classes import DEFAULT_TABLE

    if path is None:
        return DEFAULT_TABLE
    graph = default_graph()
    loaded = load_config(graph.config_stages, path, (), graph.extra_sections)
    return getattr(loaded, "classes", DEFAULT_TABLE)


def register(app: typer.Typer) -> None:
    """Add the `simulate` command."""
    app.command("simulate")(simulate_cmd)
