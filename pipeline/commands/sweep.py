"""`sonarmap sweep`: datasets x override values, locally or on Ray."""

from __future__ import annotations

from pathlib import Path

import typer

from pipeline.commands._common import CONFIG_OPT, JSON_OPT, STORE_OPT, emit_json

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("sweep")
    def sweep(
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
        json_: bool = JSON_OPT,
    ) -> None:
        """Run the cross product of DATASETS and --set values; write a mean/std table and plot."""
        import hashlib

        from pipeline.commands._common import stderr_console
        from pipeline.experiments.sweep import expand, run_sweep
        from pipeline.experiments.sweep_output import write_sweep

        specs = expand(
            datasets, set_ or (), base_overrides=fixed or (), config_path=config, store=store
        )
        from pipeline.engine.config import load_config
        from pipeline.engine.registry import all_stages, extra_sections

        # Every point's config before the first run: a bad value fails now, not hours in.
        for spec in dict.fromkeys((s.config_path, tuple(s.override_args)) for s in specs):
            load_config(all_stages(), Path(spec[0]) if spec[0] else None, spec[1], extra_sections())
        console = stderr_console()
        console.print(f"sweep: {len(specs)} runs on {executor} with {jobs} job(s)")

        def done(o: object) -> None:
            status = getattr(o, "status", "?")
            colour = "green" if status == "ok" else "red"
            console.print(
                f"[{colour}]{status}[/] {Path(getattr(o, 'dataset', '')).name} "
                f"{getattr(o, 'overrides', {})} {getattr(o, 'seconds', 0):.1f} s "
                f"{getattr(o, 'error', '') or ''}"
            )

        outcomes = run_sweep(specs, executor=executor, jobs=jobs, address=address, on_done=done)
        ident = hashlib.sha256(repr([(s.dataset, s.overrides) for s in specs]).encode()).hexdigest()
        out_dir = out or Path("data/sweeps") / ident[:12]
        doc = write_sweep(outcomes, out_dir)
        if json_:
            emit_json(doc)
        else:
            typer.echo((out_dir / "table.md").read_text())
            typer.echo(f"results: {out_dir}")
        if all(o.status != "ok" for o in outcomes):
            raise typer.Exit(1)
