"""`sonarmap label export | import`: label keyframes in CVAT or Label Studio via COCO JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from sonarmap.pipeline.commands._common import (
    CONFIG_OPT,
    JSON_OPT,
    SET_OPT,
    STORE_OPT,
    cli_graph,
    emit_json,
)

__all__ = ["label_app", "label_export", "label_import", "register"]

label_app = typer.Typer(
    help="Label keyframes in standard annotation tools (COCO JSON), and bring the labels back.",
    no_args_is_help=True,
)


def _chosen_ids(spec: str | None, every: int | None, available: list[int]) -> list[int]:
    from sonarmap.pipeline.engine.errors import ConfigError

    if spec:
        try:
            wanted = sorted({int(s) for s in spec.replace(" ", "").split(",") if s})
        except ValueError:
            raise ConfigError(
                f"--keyframes: expected ids like 3,10,42, got {spec[:40]!r}"
            ) from None
        missing = sorted(set(wanted) - set(available))
        if missing:
            raise ConfigError(
                f"--keyframes: no keyframe {missing[0]} (ids run {available[0]}..{available[-1]})"
            )
        return wanted
    return available[:: every or 1]


def _class_table(ctx: typer.Context, config: Path | None, overrides: list[str] | None) -> Any:
    """The class table of the config (section `classes`; the default without one)."""
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.schemas.classes import DEFAULT_TABLE

    graph = cli_graph(ctx)
    loaded = load_config(graph.config_stages, config, overrides or (), graph.extra_sections)
    return getattr(loaded, "classes", DEFAULT_TABLE)


def _existing_labels(
    recording: Path, frames: list[Any], table: Any
) -> tuple[dict, dict, float, list[int]]:
    """Times, shapes and tolerance of the recording's annotation file, on its keyframes."""
    import numpy as np

    from sonarmap.pipeline.engine.errors import SourceError
    from sonarmap.pipeline.training.annotations import annotation_path, load_annotations

    path = annotation_path(recording)
    if path is None:
        raise SourceError(f"{recording}: no annotation file beside it to export")
    doc = load_annotations(path, table)
    t = np.array([f.t_ns for f in frames], np.int64)
    times, shapes, ids = {}, {}, []
    for kf in doc.keyframes:
        i = int(np.argmin(np.abs(t - kf.t_ns)))
        if abs(int(t[i]) - kf.t_ns) > doc.time_tolerance_ms * 1e6:
            raise SourceError(f"{path}: t_ns {kf.t_ns} is no keyframe of this run's config")
        kid = frames[i].keyframe_id
        times[kid], shapes[kid] = kf.t_ns, kf.objects
        ids.append(kid)
    return times, shapes, doc.time_tolerance_ms, sorted(ids)


def _classifier_shapes(objects: Any, ids: set[int]) -> dict[int, list[Any]]:
    """The classifier's accepted objects on the chosen keyframes, as boxes to correct."""
    from sonarmap.schemas.annotations import AnnotatedObject, Box
    from sonarmap.schemas.classes import UNKNOWN_CLASS

    out: dict[int, list[Any]] = {}
    for row in objects.to_pylist():
        if row["keyframe_id"] in ids and row["class_name"] != UNKNOWN_CLASS:
            box = Box(**{k: row[k] for k in ("x_min_m", "x_max_m", "y_min_m", "y_max_m")})
            out.setdefault(row["keyframe_id"], []).append(
                AnnotatedObject(class_name=row["class_name"], box_m=box)
            )
    return out


def label_export(
    ctx: typer.Context,
    recording: Path = typer.Argument(..., help="The recording whose keyframes to label."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the images and COCO file."),
    keyframes: str | None = typer.Option(
        None, "--keyframes", "-k", help="Keyframe ids, comma-separated (default: all)."
    ),
    every: int | None = typer.Option(None, "--every", min=1, help="Every Nth keyframe."),
    existing: bool = typer.Option(
        False, "--existing", help="Export the keyframes and shapes of the annotation file."
    ),
    prelabel: bool = typer.Option(
        False, "--prelabel", help="Start from the classifier's objects (runs to classify)."
    ),
    pixel_m: float | None = typer.Option(
        None, "--pixel-m", min=0.001, help="Pixel side [m] (default: range resolution)."
    ),
    force: bool = typer.Option(
        False, "--force", help="Replace an earlier export in --out (its labels are lost)."
    ),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    store: Path = STORE_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Write keyframes as fan images plus a COCO file to open in CVAT or Label Studio."""
    from sonarmap.pipeline.api import RunRequest, run_dataset
    from sonarmap.pipeline.commands._errors import writes_under
    from sonarmap.pipeline.engine.store.codecs import read_verified
    from sonarmap.pipeline.labels.files import check_export_folder, export_labels

    check_export_folder(out, force)  # before any work: nothing is computed for a refusal
    table = _class_table(ctx, config, set_)
    with writes_under(store):
        until = "classify" if prelabel else "keyframes"
        request = RunRequest(
            recording, config_path=config, overrides=set_ or (), store_dir=store, until=until
        )
        graph = cli_graph(ctx)
        result, _ = run_dataset(request, graph)
        stages = {s.name: s for s in graph.stages}
        kf_stage = stages["keyframes"]
        frames_out = next(o for o in kf_stage.outputs if o.name == "frames")
        all_frames = list(read_verified(result.artifacts["keyframes"], frames_out, codecs=graph.codecs))
        if not all_frames:
            from sonarmap.pipeline.engine.errors import SourceError

            raise SourceError(f"{recording}: no keyframe to export")
        times: dict[int, int] = {}
        shapes: dict[int, Any] = {}
        tolerance = 1.0
        if existing:
            times, shapes, tolerance, ids = _existing_labels(recording, all_frames, table)
        else:
            ids = _chosen_ids(keyframes, every, [f.keyframe_id for f in all_frames])
        if prelabel:
            objects_out = next(o for o in stages["classify"].outputs if o.name == "objects")
            found = _classifier_shapes(
                read_verified(result.artifacts["classify"], objects_out), set(ids)
            )
            shapes = {**found, **shapes}
        chosen = [f for f in all_frames if f.keyframe_id in set(ids)]
        done = export_labels(recording, out, chosen, times, shapes, table.ids, tolerance, pixel_m)
    summary = {
        "folder": str(done.folder),
        "coco": str(done.coco),
        "images": done.images,
        "shapes": done.shapes,
    }
    if json_:
        emit_json(summary)
        return
    typer.echo(f"wrote {done.images} images and {done.shapes} shapes: {done.coco}")
    typer.echo("open the COCO file in CVAT or Label Studio, label, export COCO 1.0 into")
    typer.echo(f"{done.folder}, then: sonarmap label import {done.coco}")


def label_import(
    ctx: typer.Context,
    coco: Path = typer.Argument(..., help="The COCO JSON exported by the labelling tool."),
    recording: Path | None = typer.Option(
        None, "--recording", help="The recording (default: the one exported)."
    ),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Annotation file to write (default: beside the recording)."
    ),
    force: bool = typer.Option(False, "--force", help="Replace an annotation file."),
    include_empty: bool = typer.Option(
        False, "--include-empty", help="Images without shapes hold no object (else: unlabelled)."
    ),
    config: Path | None = CONFIG_OPT,
    set_: list[str] | None = SET_OPT,
    json_: bool = JSON_OPT,
) -> None:
    """Turn a COCO file's polygons and boxes into the recording's annotation file.

    Category names must be classes of the config's class table (section `classes`)."""
    from sonarmap.pipeline.labels.files import import_labels

    table = _class_table(ctx, config, set_)
    path, annotations = import_labels(
        coco, recording, out, force=force, include_empty=include_empty, table=table
    )
    n_objects = sum(len(k.objects) for k in annotations.keyframes)
    summary = {"annotations": str(path), "keyframes": len(annotations.keyframes)}
    summary["objects"] = n_objects
    if json_:
        emit_json(summary)
        return
    typer.echo(f"wrote {n_objects} objects on {len(annotations.keyframes)} keyframes: {path}")


label_app.command("export")(label_export)
label_app.command("import")(label_import)


def register(app: typer.Typer) -> None:
    app.add_typer(label_app, name="label")
