"""`sonarmap train D1.mcap D2.mcap ...`: train the object classifier on labelled datasets.

Each dataset runs through the cached graph up to `features` (keyframes with label
images, CFAR features); the classifier is then fitted by `stages.train.train_classifier`
and `model.pt`, `metrics.json` and `confusion.png` are written to --out.
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    SET_OPT,
    STORE_OPT,
    emit_json,
    stderr_console,
)

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("train")
    def train(
        datasets: list[Path] = typer.Argument(..., help="Labelled recordings (e.g. simulated)."),
        out: Path = typer.Option(
            Path("data/model"),
            "--out",
            "-o",
            help="Folder for model.pt, metrics.json, confusion.png.",
        ),
        config: Path | None = CONFIG_OPT,
        set_: list[str] | None = SET_OPT,
        store: Path = STORE_OPT,
        json_: bool = JSON_OPT,
    ) -> None:
        """Train the MC-dropout CNN classifier on labelled datasets (`train.*` config)."""
        import json

        from pipeline.api import run_dataset
        from pipeline.codecs import read_output
        from pipeline.config import section_dict
        from pipeline.errors import SourceError
        from pipeline.registry import stage_by_name
        from stages.train import TrainConfig, train_classifier

        t0 = time.perf_counter()
        inputs = []
        train_cfg: TrainConfig | None = None
        for path in datasets:
            if not path.exists():
                raise SourceError(f"{path}: no such dataset")
            result, _ = run_dataset(
                path, config_path=config, overrides=set_ or (), store_dir=store, until="features"
            )
            if train_cfg is None:
                from pipeline.api import plan_dataset

                ctx, _, _ = plan_dataset(
                    path, config_path=config, overrides=set_ or (), store_dir=store,
                    until="features", with_external=False,
                )  # fmt: skip
                train_cfg = TrainConfig(**section_dict(ctx.config, "train"))
            kf_stage, ft_stage = stage_by_name("keyframes"), stage_by_name("features")
            frames = read_output(
                result.artifacts["keyframes"].path,
                next(o for o in kf_stage.outputs if o.name == "frames"),
            )
            features = read_output(
                result.artifacts["features"].path,
                next(o for o in ft_stage.outputs if o.name == "features"),
            )
            inputs.append((frames, features))
        assert train_cfg is not None
        try:
            trained = train_classifier(inputs, train_cfg)
        except ValueError as err:
            raise SourceError(f"{', '.join(map(str, datasets))}: {err}") from err
        out.mkdir(parents=True, exist_ok=True)
        (out / "model.pt").write_bytes(trained["model"])
        (out / "metrics.json").write_text(json.dumps(trained["metrics"], indent=2, sort_keys=True))
        (out / "confusion.png").write_bytes(trained["confusion"])
        doc = {
            "datasets": [str(p) for p in datasets],
            "out": str(out),
            "seconds": round(time.perf_counter() - t0, 3),
            "metrics": trained["metrics"],
        }
        if json_:
            emit_json(doc)
            return
        console = stderr_console()
        m = trained["metrics"]
        console.print(f"model -> {out / 'model.pt'} ({doc['seconds']} s)")
        console.print(
            f"validation: n={m['n']} accuracy={m['accuracy']} accepted={m['accepted_fraction']}"
        )
        for name, c in m["classes"].items():
            console.print(
                f"  {name}: support={c['support']} precision={c['precision']} "
                f"recall={c['recall']} accepted_precision={c['accepted_precision']}"
            )
