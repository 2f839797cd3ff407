"""Horizontal-sonar features of each keyframe as planar points (paper Sec. IV.A, phi = 0)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.stages.kernels.geometry import fan_in_frame
from sonarmap.stages.slam.scan_matching import voxel_downsample

__all__ = ["keyframe_points", "leading_edges"]


def leading_edges(keyframe_id: np.ndarray, beam: np.ndarray, range_bin: np.ndarray) -> np.ndarray:
    """(N,) bool: the nearest cell of each run of consecutive detections along a beam.

    A horizontal sonar smears a vertical surface at horizontal distance d from d out to
    d / cos(aperture / 2) (the unresolved elevation), so only the first cell of a run is
    where the surface is; it is also the part that does not change with the viewpoint.

    Args:
        keyframe_id, beam, range_bin: (N,) int cells of horizontal features.
    """
    order = np.lexsort((range_bin, beam, keyframe_id))
    k, b, r = keyframe_id[order], beam[order], range_bin[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (k[1:] != k[:-1]) | (b[1:] != b[:-1]) | (r[1:] != r[:-1] + 1)
    out = np.zeros(len(order), dtype=bool)
    out[order] = first
    return out


def keyframe_points(
    keyframe_ids: np.ndarray,
    features: pa.Table,
    T_base_sonar: np.ndarray,
    voxel_m: float,
    leading_edge_only: bool = True,
) -> list[np.ndarray]:
    """Horizontal features per keyframe as (N_k, 2) base_link points at elevation 0.

    Args:
        keyframe_ids: (K,) ids in keyframe order.
        features: the features table (keyframe_id, sonar, range_bin, beam, range_m,
            angle_rad, ...).
        T_base_sonar: (4, 4) horizontal sonar mounting.
        voxel_m: voxel size of the per-keyframe downsampling.
        leading_edge_only: keep only `leading_edges` cells.
    """
    # Compared in Arrow: a million strings turned into Python objects cost ~0.1 s.
    horizontal = pc.fill_null(pc.equal(features.column("sonar"), "horizontal"), False)
    keep = horizontal.to_numpy(zero_copy_only=False)
    kf = features.column("keyframe_id").to_numpy()[keep]
    range_m = features.column("range_m").to_numpy()[keep]
    angle = features.column("angle_rad").to_numpy()[keep]
    if leading_edge_only:
        edge = leading_edges(
            kf,
            features.column("beam").to_numpy()[keep],
            features.column("range_bin").to_numpy()[keep],
        )
        kf, range_m, angle = kf[edge], range_m[edge], angle[edge]
    pts = fan_in_frame(range_m, angle, T_base_sonar)[:, :2]
    order = np.argsort(kf, kind="stable")
    kf, pts = kf[order], pts[order]
    lo = np.searchsorted(kf, keyframe_ids, side="left")
    hi = np.searchsorted(kf, keyframe_ids, side="right")
    return [voxel_downsample(pts[a:b], voxel_m) for a, b in zip(lo, hi, strict=True)]
