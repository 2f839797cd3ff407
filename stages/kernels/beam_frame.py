"""Per-beam reference frames for extended structure (beyond the paper's Sec. IV.D).

The paper registers every sighting of a class to one reference frame with ICP, which
needs the whole object in one image: a wall, a hull side or a truss "may not be fully
captured within a single image" (paper Sec. V.B), so the paper leaves them 2D. The
elevation ambiguity is the same for every class, though, and the 3D points that fusion
finds on them inside the overlap wedge are as informative as on pilings.

A frame that needs no object-level registration: along one horizontal beam, a surface
returns first at its leading edge (range R0, the nearest point inside the beam) and
then at longer ranges from points farther above or below it. Each run of an object's
returns along one beam (consecutive returns less than `gap_m` apart; a larger gap is
another surface behind, e.g. the rear members of a truss) is anchored at its own first
return, and a return at range R gets the model coordinate

    s = sqrt(R^2 - R0^2) = sqrt(u^2 + 2 R0 u),   u = R - R0,

the height at which a vertical surface through the leading edge returns at range R
(the `height_equivalent` axis of the piling models; `offset` keeps s = u). For a
vertical wall z = +-s exactly, at any distance and bearing, so one class model learns
from every fused point on every wall which of the two signs (or both) the structure
occupies at that height, and how far it departs from vertical; a hull's curved side
departs more. Optionally the anchor range R0 is a second model axis (`range_cell_m`),
for shapes whose heights change with the viewing distance.

The frame is invariant along a wall and across both of its sides (each beam anchors at
the face it sees), and a structure cut by the fan edge or the image border keeps
valid frames in all the beams it fills. The height model (`sonarmap.stages.kernels.height_model`)
stays sparse, so memory is bounded by the (s, R0) cells seen; cells it never saw
predict nothing.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

__all__ = ["BeamAxis", "beam_anchor_range", "beam_model_coords"]

BeamAxis = Literal["height_equivalent", "offset"]


def beam_anchor_range(
    object_id: np.ndarray, beam: np.ndarray, range_m: np.ndarray, gap_m: float
) -> np.ndarray:
    """Leading-edge range R0 [m] of the run along its beam that each return belongs to.

    Args:
        object_id, beam: (n,) int object and horizontal beam index of each return.
        range_m: (n,) slant range of each return [m].
        gap_m: a gap along the beam longer than this starts a new run (another surface).

    Returns:
        (n,) float64 R0 of each return, in the input order.
    """
    r = np.asarray(range_m, dtype=np.float64)
    n = r.size
    if n == 0:
        return np.zeros(0)
    order = np.lexsort((r, np.asarray(beam), np.asarray(object_id)))
    o, b, rs = np.asarray(object_id)[order], np.asarray(beam)[order], r[order]
    new_run = np.r_[True, (o[1:] != o[:-1]) | (b[1:] != b[:-1]) | (np.diff(rs) > gap_m)]
    start = np.maximum.accumulate(np.where(new_run, np.arange(n), 0))
    anchor = np.empty(n)
    anchor[order] = rs[start]
    return anchor


def beam_model_coords(
    range_m: np.ndarray,
    anchor_range_m: np.ndarray,
    axis: BeamAxis,
    range_cell_m: float | None,
) -> np.ndarray:
    """(n, 2) height-model coordinates (s, R0 or 0) of returns in their beam frames.

    Args:
        range_m, anchor_range_m: (n,) range of each return and of its run's leading edge.
        axis: "height_equivalent" (s = sqrt(R^2 - R0^2)) or "offset" (s = R - R0).
        range_cell_m: when set, the anchor range is the second coordinate (the model's
            cross-range cell size is then this); None: 0, one profile per class.
    """
    r = np.asarray(range_m, dtype=np.float64)
    r0 = np.asarray(anchor_range_m, dtype=np.float64)
    u = np.maximum(r - r0, 0.0)
    s = u if axis == "offset" else np.sqrt(u * (u + 2.0 * r0))
    second = r0 if range_cell_m is not None else np.zeros_like(r0)
    return np.stack([s, second], axis=1)
