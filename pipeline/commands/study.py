"""`sonarmap study`: the paper's simulation study (Table I analogue) in one command."""

from __future__ import annotations

from pathlib import Path

import typer

from pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json

__all__ = ["PAPER_TABLE_I", "register"]

PAPER_TABLE_I = {
    "4": {"standard": (2938.6, 984.18), "semantic": (60091.4, 20038.116)},
    "2": {"standard": (3549.4, 1144.72), "semantic": (68422.2, 25518.37)},
}
"""McConnell & Englot (ICRA 2021), Table I: mean and std of 10 cm voxel counts, 10 trials."""


def table_i(groups: list[dict]) -> str:
    """Markdown of our figures beside the paper's, one row per spacing and map."""
    lines = [
        "| map | spacing | voxels (ours, mean ± std) | voxels (paper) | semantic/standard (ours) | (paper) | median error m (ours) |",
        "|---|---|---|---|---|---|---|",
    ]
    for g in sorted(groups, key=lambda g: -float(g["overrides"].get("keyframes.spacing_m", 0))):
        spacing = str(g["overrides"].get("keyframes.spacing_m", "?")).rstrip("0").rstrip(".")
        paper = PAPER_TABLE_I.get(spacing, {})
        for name in ("standard", "semantic"):
            ours = g.get(f"voxels_{name}", {})
            err = g.get(f"median_error_{name}_m", {})
            p = paper.get(name)
            ratio = g.get("ratio", {}).get("mean") if name == "semantic" else None
            p_ratio = (
                paper["semantic"][0] / paper["standard"][0]
                if paper and name == "semantic"
                else None
            )
            lines.append(
                f"| {name} | {spacing} m | "
                + ("-" if ours.get("mean") is None else f"{ours['mean']:.0f} ± {ours['std']:.0f}")
                + f" | {'-' if p is None else f'{p[0]:.0f} ± {p[1]:.0f}'} | "
                + ("" if ratio is None else f"{ratio:.1f}x")
                + f" | {'' if p_ratio is None else f'{p_ratio:.1f}x'} | "
                + ("-" if err.get("mean") is None else f"{err['mean']:.3f}")
                + " |"
            )
    return "\n".join(lines) + "\n"


def register(app: typer.Typer) -> None:
    @app.command("study")
    def study(
        trials: int = typer.Option(10, "--trials", min=1, help="Simulated trials (seeds 0..N-1)."),
        goals: int = typer.Option(20, "--goals", min=1, help="Random goals per trial."),
        scene: str = typer.Option("marina", "--scene", help="Scene name or YAML path."),
        spacings: str = typer.Option("2,4", "--spacings", help="Keyframe spacings [m]."),
        executor: str = typer.Option("local", "--executor", help="local or ray."),
        jobs: int = typer.Option(1, "--jobs", "-j", help="Parallel runs."),
        out: Path = typer.Option(Path("data/study"), "--out", help="Datasets and results folder."),
        store: Path = STORE_OPT,
        json_: bool = JSON_OPT,
    ) -> None:
        """Simulate N trials, map each at 2 m and 4 m spacing with true poses, print Table I."""
        import time

        from pipeline.commands._common import stderr_console
        from pipeline.datasets import ensure_simulation, scene_path
        from pipeline.sweep import expand, run_sweep
        from pipeline.sweep_output import write_sweep

        console = stderr_console()
        t0 = time.perf_counter()
        scene_file = scene_path(scene)
        datasets = []
        for seed in range(trials):
            path = out / f"{scene_file.stem}-goals{goals}-seed{seed}.mcap"
            console.print(f"trial {seed}: {path}")
            datasets.append(ensure_simulation(scene_file, seed, path, goals=goals))
        specs = expand(
            datasets,
            [f"keyframes.spacing_m={spacings}"],
            base_overrides=["slam.mode=ground_truth"],
            store=store,
        )
        outcomes = run_sweep(
            specs,
            executor=executor,
            jobs=jobs,
            on_done=lambda o: console.print(
                f"{o.status} {Path(o.dataset).name} {o.overrides} {o.seconds:.0f} s {o.error or ''}"
            ),
        )
        doc = write_sweep(outcomes, out / "results")
        markdown = table_i(doc["groups"])
        (out / "results" / "table_i.md").write_text(markdown)
        doc["table_i"] = markdown
        doc["wall_s"] = round(time.perf_counter() - t0, 1)
        if json_:
            emit_json(doc)
        else:
            typer.echo(markdown)
            typer.echo(f"wall time {doc['wall_s']} s; results in {out / 'results'}")
