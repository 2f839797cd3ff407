"""One keyframe's objects and their CNN beliefs, as a work unit (`sonarmap.stages.base.Units`).

A unit holds what `classify` computes of one keyframe alone: its objects (clusters of
its horizontal features: sizes, boxes, centroids, true classes when labelled, which
features each holds) and the mean and variance of the MC-dropout class probabilities of
their patches (`cnn.mc_predict_groups` over that keyframe's patches only, with its own
seed). Pooling over views, which mixes keyframes, runs after, on the assembled rows.

Key: sha256 of the stage's name and version, its config (the model-choice fields left
out, as in the stage key: the model enters by the sha256 of its bytes; and the decision
fields, `DECISION_FIELDS`, which act on the assembled rows only), the class table,
the keyframe's dropout seed (from its ping time), and the digest of its horizontal image,
axes and label image with its feature rows (positions, not ids): the same pings give the
same unit at any keyframe spacing.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sonarmap.schemas.model_settings import ModelSettings
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import Units
from sonarmap.stages.kernels.lazy import lazy
from sonarmap.stages.kernels.unit_keys import array_digest, unit_key

cnn = lazy("sonarmap.stages.classify.cnn")

__all__ = ["DECISION_FIELDS", "KeyframeResult", "classify_base", "keyframe_result"]

DECISION_FIELDS: tuple[str, ...] = (
    "threshold", "pool_views", "pool_radius_m", "pool_window_m", "pool_range_scale_m",
    "min_views", "min_seen_share",
)  # fmt: skip
"""Settings of the decision taken after pooling, on the whole recording's rows: a
keyframe's objects and beliefs do not depend on them, so a sweep over them reuses every
keyframe's CNN work."""

_FEATURE_COLUMNS = ("range_bin", "beam", "range_m", "angle_rad")
"""What the key takes of the keyframe's features: not their ids, which number them
through the recording (the unit's `feature_index` counts rows of the keyframe's own)."""


@dataclass(frozen=True)
class KeyframeResult:
    """One keyframe's objects (`objects.KeyframeObjects` less the patches) and beliefs."""

    feature_index: np.ndarray
    object_index: np.ndarray
    boxes: np.ndarray
    centroid_xy: np.ndarray
    n_features: np.ndarray
    true_class_id: np.ndarray | None
    mean: np.ndarray
    var: np.ndarray

    @property
    def count(self) -> int:
        return len(self.boxes)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {k: v for k, v in self.__dict__.items() if v is not None}
        out["has_truth"] = np.array([self.true_class_id is not None], np.int8)
        return out

    @classmethod
    def of(cls, arrays: Mapping[str, Any]) -> KeyframeResult:
        got = {k: np.asarray(v) for k, v in arrays.items()}
        truth = got.pop("true_class_id", None) if int(got.pop("has_truth")[0]) else None
        got.pop("true_class_id", None)
        return cls(**got, true_class_id=truth)


def classify_base(
    name: str, version: int, config: Any, excluded: tuple[str, ...], model_bytes: bytes,
    table: Any, model_settings: Mapping[str, Any] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """What every keyframe's unit key shares (`model_settings`: the class names and
    settings the run reads the model's beliefs with)."""
    return {
        "stage": name,
        "version": version,
        "config": config.model_dump(mode="json", exclude={*excluded, *DECISION_FIELDS}),
        "model": hashlib.sha256(model_bytes).hexdigest(),
        "model_settings": model_settings,
        "classes": table.model_dump(mode="json") if hasattr(table, "model_dump") else repr(table),
    }


def _digest(frame: KeyframeImages, f: Mapping[str, np.ndarray]) -> str:
    ping = frame.horizontal
    labels = () if ping.labels is None else (ping.labels,)
    cols = tuple(np.asarray(f[c]) for c in _FEATURE_COLUMNS)
    return array_digest(ping.image, ping.ranges_m, ping.angles_rad, *labels, *cols)


def keyframe_result(
    frame: KeyframeImages,
    f: Mapping[str, np.ndarray],
    extract: Any,
    model: Any,
    n_classes: int,
    settings: ModelSettings,
    cfg: Any,
    seed: int,
    base: Mapping[str, Any],
    units: Units | None,
) -> KeyframeResult:
    """One keyframe's objects and beliefs: from `units`, or computed (and stored there).

    `extract(frame, f)` finds the keyframe's objects (`objects.extract_objects` with the
    stage's settings); `model()` gives the CNN (loaded on the first call: a keyframe found
    in `units` needs none); beliefs are zeros when labels come from the ground truth.
    """
    key = None
    if units is not None:
        key = unit_key({**base, "seed": seed, "frame": _digest(frame, f)})
        got = units.get(key)
        if got is not None:
            return KeyframeResult.of(got)
    objs = extract(frame, f)
    if cfg.labels == "ground_truth" or objs.count == 0:
        mean = var = np.zeros((objs.count, n_classes))
    else:
        mean, var = cnn.mc_predict_groups(
            model(), objs.patches, [objs.count], [seed], cfg.mc_passes
        )
    found = KeyframeResult(
        objs.feature_index, objs.object_index, objs.boxes, objs.centroid_xy, objs.n_features,
        objs.true_class_id, mean, var,
    )  # fmt: skip
    if units is not None and key is not None:
        units.put(key, found.arrays())
    return found
