"""`sonarmap train D1.mcap D2.mcap ...`: train the object classifier on labelled datasets.

Each dataset runs through the cached graph up to `features` (keyframes with label
images, CFAR features, with the `training.keyframes`/`training.features` settings unless
`training.follow_run`), then the cached `train` stage (`sonarmap.pipeline.training.model.train_on`);
`model.pt`, `metrics.json` and `confusion.png` are copied from its artifact to --out.
A recording with `<stem>.annotations.yaml` beside it (field data) is labelled by that
file instead of label images (format: docs/labels-and-classes.md, `sonarmap.schemas.annotations`).

`sonarmap train` without datasets builds (or finds) the default model of the `training`
section, procedural worlds included, and copies it to --out.

`sonarmap train --ship` takes no datasets: it resolves the default model of the
`training` section (simulating and training only what this machine lacks) and writes it,
with the lock of its training recordings, to `training.shipped_models`
(`sonarmap.pipeline.training.shipped`), so that fresh clones use it instead of training.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    SET_OPT,
    STORE_OPT,
    cli_graph,
    emit_json,
    stderr_console,
)

__all__ = ["register", "train"]


def train(
    ctx: typer.Context,
    datasets: list[Path] | None = typer.Argument(
        None,
        help="Labelled recordings: simulated (label images) or with "
        "<stem>.annotations.yaml beside them.",
    ),
    out: Path = typer.Option(
        Path("data/model"),
        "--out",
        "-o",
        help="Folder for model.pt, metrics.json, confusion.png.",
    ),
    ship: bool = typer.Option(
        False,
        "--ship",
        help="Write the default model and its training recordings' lock to "
        "training.shipped_models (no datasets).",
    ),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    store: Path = STORE_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Train the MC-dropout CNN classifier on labelled datasets (`train.*` config)."""
    import shutil

    if ship:
        if datasets:
            raise typer.BadParameter("--ship trains the default model; give no datasets")
        _ship(config, set_ or (), store, json_)
        return
    if not datasets:
        _default(config, set_ or (), store, out, json_)
        return

    from sonarmap.pipeline.api import RunRequest, plan_dataset
    from sonarmap.pipeline.commands._errors import check_writable, writes_under
    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.training.annotations import annotation_path
    from sonarmap.pipeline.training.model import train_on

    with writes_under(out, store):
        t0 = time.perf_counter()
        seen: dict[Path, Path] = {}
        for path in datasets:
            if not path.exists():
                raise SourceError(f"{path}: no such dataset")
            # one recording twice (another path, a link) would count its objects twice
            if (same := seen.setdefault(path.resolve(), path)) is not path:
                also = "given twice" if same == path else f"the same recording as {same}"
                raise SourceError(f"{path}: {also}; give each recording once")
        check_writable(out)  # before training, not after
        request = RunRequest(
            datasets[0],
            config_path=config,
            overrides=set_ or (),
            store_dir=store,
            until="features",
        )
        context, _, _ = plan_dataset(request, cli_graph(ctx), with_external=False)
        try:
            ref = train_on(datasets, context.config, context.store)
        except ValueError as err:
            raise SourceError(f"{', '.join(map(str, datasets))}: {err}") from err
        out.mkdir(parents=True, exist_ok=True)
        from sonarmap.pipeline.engine.store.integrity import verify_file

        # Every file and the manifest: the folder is then a model a run can be pointed
        # at (`--set classify.model=DIR`), checked against the manifest's sha256s.
        for name in ref.manifest.get("files", {}):
            shutil.copyfile(verify_file(ref, name), out / name)
        shutil.copyfile(ref.path / "manifest.json", out / "manifest.json")
        metrics = json.loads((ref.path / "metrics.json").read_text())
        trained = {"metrics": metrics}
        doc = {
            "datasets": [str(p) for p in datasets],
            "annotations": {
                str(p): str(a) if (a := annotation_path(p)) else None for p in datasets
            },
            "out": str(out),
            "artifact": str(ref.path),
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


def _default(
    config: Path | None, overrides: list[str] | tuple[str, ...], store: Path, out: Path, json_: bool
) -> None:
    """`train` without datasets: the default model of the `training` section (procedural
    worlds, `training.sets`, `training.recorded`), resolved as a run would (the store,
    the model cache or the shipped model, else simulated and trained), copied to --out."""
    import shutil

    from sonarmap.pipeline.commands._errors import check_writable, writes_under
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
    from sonarmap.pipeline.engine.store.integrity import verify_file
    from sonarmap.pipeline.graph import all_stages, extra_sections
    from sonarmap.pipeline.readers.referenced_files import pin_referenced_files
    from sonarmap.pipeline.training.model_cache import resolve_default_model

    with writes_under(out, store):
        t0 = time.perf_counter()
        check_writable(out)
        resolved = pin_referenced_files(
            load_config(all_stages(), config, overrides, extra_sections())
        )
        chosen = resolve_default_model(ArtifactStore(store), resolved)
        ref = chosen.ref
        out.mkdir(parents=True, exist_ok=True)
        for name in ref.manifest.get("files", {}):
            shutil.copyfile(verify_file(ref, name), out / name)
        shutil.copyfile(ref.path / "manifest.json", out / "manifest.json")
        metrics = json.loads((ref.path / "metrics.json").read_text())
        doc = {
            "default": True,
            "source": chosen.source,
            "out": str(out),
            "artifact": str(ref.path),
            "seconds": round(time.perf_counter() - t0, 3),
            "metrics": metrics,
        }
        if json_:
            emit_json(doc)
            return
        console = stderr_console()
        curve = metrics.get("size_rule") or {}
        console.print(f"default model ({chosen.source}) -> {out / 'model.pt'} ({doc['seconds']} s)")
        console.print(
            f"validation: n={metrics['n']} accuracy={metrics['accuracy']}; size rule chose"
            f" {curve.get('chosen_datasets')} datasets: "
            + ", ".join(f"{p['datasets']}: {p['macro_f1']}" for p in curve.get("points", []))
        )


def register(app: typer.Typer) -> None:
    app.command("train")(train)


def _ship(
    config: Path | None, overrides: list[str] | tuple[str, ...], store: Path, json_: bool
) -> None:
    """`train --ship`: the default model, resolved as a run would, into the shipped folder."""
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.engine.errors import ConfigError
    from sonarmap.pipeline.engine.run.session import dataset_spec
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
    from sonarmap.pipeline.graph import all_stages, default_graph, extra_sections
    from sonarmap.pipeline.readers.referenced_files import pin_referenced_files
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.model import training_datasets, training_simulations
    from sonarmap.pipeline.training.model_cache import resolve_default_model
    from sonarmap.pipeline.training.shipped import lock_disagreements, ship, shipped_root

    resolved = pin_referenced_files(load_config(all_stages(), config, overrides, extra_sections()))
    training: TrainingDataConfig = getattr(resolved, "training", TrainingDataConfig())
    root = shipped_root(training.shipped_models)
    if root is None:
        raise ConfigError("training.shipped_models: null, so there is nowhere to ship to")
    if training.recorded:
        raise ConfigError("training.recorded: a shipped model is trained on simulations only")
    sims = training_simulations(training)
    paths = training_datasets(training)
    run_store = ArtifactStore(store)
    chosen = resolve_default_model(run_store, resolved)
    fingerprints = [dataset_spec(p, run_store, default_graph()).fingerprint for p in paths]
    on_disk = dict(zip(paths, fingerprints, strict=True))
    for line in lock_disagreements(sims, on_disk, training.shipped_models):
        logging.getLogger(__name__).warning(
            "%s; --ship writes this machine's bytes in the lock", line
        )
    ship(chosen.ref, sims, fingerprints, root)
    doc = {"shipped": str(root), "key": chosen.ref.key, "source": chosen.source}
    if json_:
        emit_json(doc)
        return
    stderr_console().print(f"shipped train/{chosen.ref.key[:12]} -> {root}")
