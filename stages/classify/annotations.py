"""Hand-drawn annotations -> label images on the horizontal sonar's polar grid.

Field recordings have no simulator label images. `label_keyframes` rasterises an
annotation file's boxes and polygons (`sonarmap.schemas.annotations`, drawn in the fan-plane
Cartesian frame x = R cos(theta), y = R sin(theta), paper Eq. 1 with phi = 0) onto
each annotated keyframe's polar cells, so training takes the majority class of each
DBSCAN cluster's cells (paper Sec. IV.C) exactly as it does from simulated labels.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Iterator, Sequence

import numpy as np
import pyarrow as pa

from sonarmap.schemas.annotations import AnnotatedObject, AnnotationFile
from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.classify.config import RASTER_VERSION
from sonarmap.stages.kernels.geometry import fan_to_xy
from sonarmap.stages.kernels.lazy import lazy

mpath = lazy("matplotlib.path")

__all__ = [
    "RASTER_VERSION",
    "UnmatchedAnnotations",
    "label_keyframes",
    "objects_without_features",
    "rasterise",
]

log = logging.getLogger(__name__)

SHOWN_TIMES = 5
"""Unmatched annotation times quoted in a message (the rest are counted)."""


class UnmatchedAnnotations(ValueError):
    """No annotated time matches a keyframe: bad input (the file or the recording), not a bug."""


def _times(times: list[int]) -> str:
    shown = ", ".join(str(t) for t in times[:SHOWN_TIMES])
    return shown + (f", ... ({len(times) - SHOWN_TIMES} more)" if len(times) > SHOWN_TIMES else "")


def rasterise(
    ping: SonarPing, objects: Iterable[AnnotatedObject], table: ClassTable = DEFAULT_TABLE
) -> np.ndarray:
    """Label image of one horizontal ping from its annotated shapes.

    A cell takes the class of the last shape that contains its centre (range bin
    centre, beam angle); cells in no shape are 0 ("none").

    Args:
        ping: the horizontal sonar image (its ranges and beam angles define the grid).
        objects: shapes in the sonar frame (x forward, y left) [m].
        table: the class table giving each class name its label id.

    Returns:
        (n_ranges, n_beams) uint8 class ids.
    """
    r = np.asarray(ping.ranges_m, np.float64)[:, None]
    a = np.asarray(ping.angles_rad, np.float64)[None, :]
    x, y = fan_to_xy(r, a).reshape(-1, 2).T
    out = np.zeros(x.shape, np.uint8)
    for obj in objects:
        poly = np.asarray(obj.vertices_m(), np.float64)
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        # The bounding-box test is cheap on every cell; the exact test only runs near the shape.
        near = np.flatnonzero((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]))
        if len(near) == 0:
            continue
        inside = mpath.Path(poly).contains_points(np.stack([x[near], y[near]], axis=1))
        out[near[inside]] = table.ids[obj.class_name]
    return out.reshape(len(ping.ranges_m), len(ping.angles_rad))


def objects_without_features(
    objects: Sequence[AnnotatedObject], range_m: np.ndarray, angle_rad: np.ndarray
) -> list[int]:
    """Indices of the annotated shapes that hold none of a keyframe's horizontal features
    (range [m], bearing [rad]): they label no detected object, so they train nothing."""
    xy = fan_to_xy(range_m, angle_rad).reshape(-1, 2)
    empty = []
    for i, obj in enumerate(objects):
        if len(xy) == 0 or not mpath.Path(np.asarray(obj.vertices_m())).contains_points(xy).any():
            empty.append(i)
    return empty


def _horizontal_features(features: pa.Table | None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    if features is None:
        return {}
    horizontal = np.asarray(features.column("sonar").to_pylist(), dtype=object) == "horizontal"
    kf = features.column("keyframe_id").to_numpy()[horizontal]
    r = features.column("range_m").to_numpy()[horizontal]
    a = features.column("angle_rad").to_numpy()[horizontal]
    order = np.argsort(kf, kind="stable")
    ids, starts = np.unique(kf[order], return_index=True)
    bounds = [*starts[1:], len(order)]
    return {
        int(k): (r[order[s:e]], a[order[s:e]]) for k, s, e in zip(ids, starts, bounds, strict=True)
    }


def label_keyframes(
    frames: Iterable[KeyframeImages],
    annotations: AnnotationFile,
    *,
    source: str = "annotations",
    features: pa.Table | None = None,
    table: ClassTable = DEFAULT_TABLE,
) -> Iterator[KeyframeImages]:
    """The annotated keyframes, their horizontal label images replaced by the annotations.

    A keyframe is annotated when an entry's t_ns lies within `time_tolerance_ms` of its
    t_ns (the nearest entry wins); other keyframes are skipped. Any label image the
    recording carried is discarded, so annotations are the only truth.

    Args:
        frames: keyframes in any order (read lazily, one at a time).
        annotations: the validated annotation file.
        source: name used in messages (the file).
        features: the recording's features table; shapes holding none of their
            keyframe's horizontal features are then named in a warning.
        table: the class table (label ids of the annotated class names).

    Yields:
        Annotated keyframes with `horizontal.labels` set (uint8 class ids).

    Raises:
        UnmatchedAnnotations: after the last keyframe, if no entry matched any keyframe
            (entries that match none while others match are a logged warning).
    """
    entries = sorted(annotations.keyframes, key=lambda k: k.t_ns)
    times = np.array([k.t_ns for k in entries], np.int64)
    tol_ns = annotations.time_tolerance_ms * 1e6
    used: set[int] = set()
    by_keyframe = _horizontal_features(features)
    no_features: list[str] = []
    n_frames = 0
    lo_t, hi_t = np.iinfo(np.int64).max, np.iinfo(np.int64).min
    for frame in frames:
        n_frames += 1
        lo_t, hi_t = min(lo_t, frame.t_ns), max(hi_t, frame.t_ns)
        i = int(np.searchsorted(times, frame.t_ns))
        near = [j for j in (i - 1, i) if 0 <= j < len(times)]
        j = min(near, key=lambda j: abs(int(times[j]) - frame.t_ns))
        if abs(int(times[j]) - frame.t_ns) > tol_ns:
            continue
        used.add(j)
        if features is not None:
            r, a = by_keyframe.get(frame.keyframe_id, (np.zeros(0), np.zeros(0)))
            for k in objects_without_features(entries[j].objects, r, a):
                no_features.append(
                    f"t_ns {times[j]} object {k} ({entries[j].objects[k].class_name})"
                )
        labels = rasterise(frame.horizontal, entries[j].objects, table)
        yield dataclasses.replace(
            frame, horizontal=dataclasses.replace(frame.horizontal, labels=labels)
        )
    if not used:
        span = f", {lo_t} .. {hi_t}" if n_frames else ""
        raise UnmatchedAnnotations(
            f"{source}: keyframes[].t_ns: none of its {len(times)} annotated times "
            f"({_times(times.tolist())}) is within {annotations.time_tolerance_ms:g} ms of "
            f"one of the {n_frames} keyframes' t_ns{span}"
        )
    if no_features:
        log.warning(
            "%s: %d annotated shapes hold no detected feature and train nothing: %s%s"
            " (draw shapes over the returns; axes: x forward, y left, metres)",
            source, len(no_features), "; ".join(no_features[:SHOWN_TIMES]),
            f"; ... ({len(no_features) - SHOWN_TIMES} more)" if len(no_features) > SHOWN_TIMES else "",
        )  # fmt: skip
    if len(used) < len(times):
        unmatched = [int(t) for j, t in enumerate(times) if j not in used]
        log.warning(
            "%s: %d of %d annotated times match no keyframe and are not trained on "
            "(t_ns %s; not selected by the keyframe spacing, or not in the recording)",
            source, len(unmatched), len(times), _times(unmatched),
        )  # fmt: skip
