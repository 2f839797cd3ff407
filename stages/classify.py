"""The "classify" stage: objects of every keyframe and their classes (paper Sec. IV.C).

Per keyframe: DBSCAN clusters of the horizontal sonar's features (metric fan-plane
coordinates), clusters of at least n features, 40x40 aspect-preserving patches, and m
Monte-Carlo dropout passes of the CNN batched into one forward call. An object takes the
argmax class of the mean softmax when that mean probability exceeds the threshold and
is "unknown" otherwise; mean and variance are recorded. Dropout masks are seeded per
keyframe (seed, keyframe_id), so outputs are byte-identical run to run.

The patch geometry (margin, smallest side) comes from the model file, so patches are
cut exactly as in training; the clustering parameters are this stage's config.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
from pydantic import Field

from schemas.classes import CLASS_IDS, CLASS_NAMES, UNKNOWN_CLASS
from schemas.objects import OBJECT_FEATURES_SCHEMA, OBJECTS_SCHEMA, UNKNOWN_CLASS_ID
from schemas.sonar import KeyframeImages
from stages._lazy import lazy
from stages.base import Output, Stage, StageConfig
from stages.objects import KeyframeObjects, extract_objects, horizontal_features

if TYPE_CHECKING:
    from stages.cnn import PatchCNN

cnn = lazy("stages.cnn")

__all__ = ["STAGE", "ClassifyConfig", "classify_keyframes", "overlay_png"]

log = logging.getLogger(__name__)

_SEED_STRIDE = 1_000_003


class ClassifyConfig(StageConfig):
    """DBSCAN clustering and MC-dropout acceptance (paper Sec. IV.C).

    The clustering defaults live once, in `stages.train.TrainConfig`: a model is trained
    on the objects its clustering produces, so classify reads them from the model file
    and these fields only override them (an override outside what the model saw in
    training changes what it is shown).
    """

    eps_m: float | None = Field(
        None, gt=0, description="DBSCAN radius [m]; None: the model's (train.eps_m)"
    )
    min_samples: int | None = Field(
        None, ge=1, description="DBSCAN core neighbourhood; None: the model's (train.min_samples)"
    )
    min_features: int | None = Field(
        None, ge=1, description="smallest object kept; None: the model's (train.min_features)"
    )
    mc_passes: int = Field(20, ge=1, description="Monte-Carlo dropout passes m")
    threshold: float = Field(0.99, ge=0, le=1, description="accept when mean probability > this")
    seed: int = Field(0, description="dropout-mask seed (combined with keyframe_id)")
    overlay: bool = Field(True, description="render overlay.png of the busiest keyframe")


def _clustering(cfg: ClassifyConfig, model_config: Mapping[str, Any], name: str) -> float:
    """A clustering parameter: the config's override, else the model file's."""
    value = getattr(cfg, name)
    if value is not None:
        return float(value)
    if name not in model_config:
        raise ValueError(f"train.model: the model file has no {name!r}; set classify.{name}")
    return float(model_config[name])


def _empty_features() -> dict[str, np.ndarray]:
    z_i, z_f = np.zeros(0, np.int64), np.zeros(0, np.float64)
    return {"feature_id": z_i, "range_bin": z_i, "beam": z_i, "range_m": z_f, "angle_rad": z_f}


def _object_rows(
    frame: KeyframeImages, objs: KeyframeObjects, mean: np.ndarray, var: np.ndarray,
    class_ids: np.ndarray, names: list[str], first_id: int, threshold: float,
) -> dict[str, Any]:  # fmt: skip
    """Columns of objects.parquet for one keyframe's k objects."""
    k = objs.count
    best = mean.argmax(axis=1) if k else np.zeros(0, np.int64)
    p = mean[np.arange(k), best] if k else np.zeros(0)
    accepted = p > threshold
    argmax_names = [names[i] for i in best]
    truth = objs.true_class_id
    cx, cy = objs.centroid_xy[:, 0], objs.centroid_xy[:, 1]
    return {
        "keyframe_id": np.full(k, frame.keyframe_id, np.int64),
        "object_id": np.arange(first_id, first_id + k, dtype=np.int64),
        "class_id": np.where(accepted, class_ids[best], UNKNOWN_CLASS_ID).astype(np.int64),
        "class_name": [n if a else UNKNOWN_CLASS for n, a in zip(argmax_names, accepted, strict=True)],
        "argmax_class_name": argmax_names,
        "probability": p.astype(np.float64),
        "probability_var": var[np.arange(k), best].astype(np.float64) if k else np.zeros(0),
        "n_features": objs.n_features,
        "x_m": cx, "y_m": cy, "range_m": np.hypot(cx, cy), "bearing_rad": np.arctan2(cy, cx),
        "x_min_m": objs.boxes[:, 0], "x_max_m": objs.boxes[:, 1],
        "y_min_m": objs.boxes[:, 2], "y_max_m": objs.boxes[:, 3],
        "true_class_name": [CLASS_NAMES[c] for c in truth] if truth is not None else [None] * k,
    }  # fmt: skip


def classify_keyframes(
    frames: Iterable[KeyframeImages],
    features: pa.Table,
    model: PatchCNN,
    class_names: list[str],
    model_config: Mapping[str, Any],
    cfg: ClassifyConfig,
) -> tuple[pa.Table, pa.Table, tuple[KeyframeImages, pa.Table] | None]:
    """Objects and classes of every keyframe.

    Args:
        frames: keyframe images in keyframe order (held one at a time).
        features: features.parquet (only horizontal rows are used).
        model: the classifier; class_names: its output names; model_config: the
            model file's config (clustering `eps_m`, `min_samples`, `min_features`;
            patch `margin_m`, `min_side_m`, `size_px`).
        cfg: clustering and acceptance config.

    Returns:
        (objects table, object_features table, (busiest keyframe, its objects) or None);
        the busiest keyframe has the most accepted objects.
    """
    by_kf = horizontal_features(features)
    eps_m = float(_clustering(cfg, model_config, "eps_m"))
    min_samples = int(_clustering(cfg, model_config, "min_samples"))
    min_features = int(_clustering(cfg, model_config, "min_features"))
    class_ids = np.array([CLASS_IDS[n] for n in class_names], np.int64)
    obj_parts: list[pa.Table] = []
    link_parts: list[pa.Table] = []
    next_id = 0
    busiest: tuple[int, KeyframeImages, pa.Table] | None = None
    for frame in frames:
        f = by_kf.get(frame.keyframe_id) or _empty_features()
        objs = extract_objects(
            frame.horizontal, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
            eps_m=eps_m, min_samples=min_samples, min_features=min_features,
            margin_m=float(model_config["margin_m"]), min_side_m=float(model_config["min_side_m"]),
            size_px=int(model_config["size_px"]),
        )  # fmt: skip
        seed = cfg.seed * _SEED_STRIDE + frame.keyframe_id
        mean, var = cnn.mc_predict(model, objs.patches, cfg.mc_passes, seed)
        cols = _object_rows(frame, objs, mean, var, class_ids, class_names, next_id, cfg.threshold)
        table = pa.Table.from_pydict(cols, schema=OBJECTS_SCHEMA)
        obj_parts.append(table)
        link_parts.append(
            pa.Table.from_pydict(
                {
                    "keyframe_id": np.full(len(objs.feature_index), frame.keyframe_id, np.int64),
                    "object_id": next_id + objs.object_index,
                    "feature_id": f["feature_id"][objs.feature_index].astype(np.int64),
                },
                schema=OBJECT_FEATURES_SCHEMA,
            ).sort_by([("object_id", "ascending"), ("feature_id", "ascending")])
        )
        next_id += objs.count
        n_acc = int(np.sum(cols["class_id"] != UNKNOWN_CLASS_ID))
        if cfg.overlay and objs.count and (busiest is None or n_acc > busiest[0]):
            busiest = (n_acc, frame, table)
    objects = pa.concat_tables(obj_parts) if obj_parts else OBJECTS_SCHEMA.empty_table()
    links = pa.concat_tables(link_parts) if link_parts else OBJECT_FEATURES_SCHEMA.empty_table()
    log.info("classified %d objects in %d keyframes", objects.num_rows, len(obj_parts))
    return objects, links, (busiest[1], busiest[2]) if busiest else None


def overlay_png(frame: KeyframeImages, objects: pa.Table) -> bytes:
    """Class-coloured overlay of one keyframe: the horizontal image in fan-plane Cartesian
    coordinates with each object's bounding box and label (class, probability; truth).

    Args:
        frame: the keyframe.
        objects: that keyframe's rows of objects.parquet.

    Returns:
        PNG bytes.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    ping = frame.horizontal
    step_r = max(1, len(ping.ranges_m) // 300)
    step_b = max(1, len(ping.angles_rad) // 256)
    r = ping.ranges_m[::step_r, None].astype(np.float64)
    a = ping.angles_rad[None, ::step_b].astype(np.float64)
    fig = Figure(figsize=(8, 6), dpi=100)
    ax = fig.add_subplot()
    img = ping.image[::step_r, ::step_b]
    vmin, vmax = float(np.percentile(img, 90)), max(float(img.max()), 1.0)
    ax.pcolormesh(-r * np.sin(a), r * np.cos(a), img, cmap="gray", vmin=vmin, vmax=vmax,
                  shading="auto", rasterized=True)  # fmt: skip
    cmap = matplotlib.colormaps["tab10"]
    for row in objects.to_pylist():
        cid = CLASS_IDS.get(row["class_name"], 0)
        colour = cmap(cid % 10) if row["class_id"] >= 0 else (1.0, 1.0, 1.0, 1.0)
        x0, x1, y0, y1 = row["x_min_m"], row["x_max_m"], row["y_min_m"], row["y_max_m"]
        ax.add_patch(Rectangle((-y1, x0), y1 - y0, x1 - x0, fill=False, lw=1.2, ec=colour))
        text = f"{row['class_name']} {row['probability']:.2f}"
        if row["true_class_name"] is not None:
            text += f"\n(true {row['true_class_name']})"
        ax.text(-y1, x1, text, color=colour, fontsize=6, va="bottom")
    ax.set_aspect("equal")
    ax.set_xlabel("-y (right) [m]")
    ax.set_ylabel("x (forward) [m]")
    ax.set_title(f"keyframe {frame.keyframe_id}: horizontal sonar objects")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _run(config: ClassifyConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    with cnn.fixed_threads(1):
        return _classify(config, inputs)


def _classify(config: ClassifyConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    model_bytes = inputs["train.model"]
    if not isinstance(model_bytes, bytes | bytearray):
        raise ValueError(f"train.model must be bytes, got {type(model_bytes).__name__}")
    model, names, mcfg = cnn.model_from_bytes(bytes(model_bytes))
    objects, links, busiest = classify_keyframes(
        inputs["keyframes.frames"], inputs["features.features"], model, names, mcfg, config
    )
    overlay = overlay_png(*busiest) if busiest is not None else None
    return {"objects": objects, "object_features": links, "overlay": overlay}


STAGE = Stage(
    name="classify",
    version=3,
    config=ClassifyConfig,
    inputs=("keyframes.frames", "features.features", "train.model"),
    outputs=(
        Output("objects", "parquet", "objects.parquet", schema=OBJECTS_SCHEMA),
        Output(
            "object_features", "parquet", "object_features.parquet", schema=OBJECT_FEATURES_SCHEMA
        ),
        Output("overlay", "bytes", "overlay.png", optional=True),
    ),
    run=_run,
    description="DBSCAN objects of horizontal features, classified by an MC-dropout CNN",
)
