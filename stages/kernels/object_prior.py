"""Per-object height prior for the beam-frame class models (hierarchical pooling).

A beam-frame class model (`sonarmap.stages.kernels.beam_frame`) pools every object of a class:
P(z | s) learned from all their fused points. Where the class's objects sit at different
heights relative to the sonar (a hull floats at the surface whatever the sonar's depth; a
truss spans its own band of heights), that pooled posterior is wide, and its MAP height
(paper Eq. 8-9) lands between the objects' bands.

The fused points of the object itself, in the same image, say which band it occupies.
This module turns them into a prior over the z grid, a kernel density of the object's
fused heights with a floor, which multiplies the class posterior of each of the object's
2D-only returns before the MAP: the class model says where along the beam each height
returns from, the object's own points say which heights this object has. An object with
no fused point gets a flat prior (the class posterior unchanged).
"""

from __future__ import annotations

import numpy as np

__all__ = ["object_height_prior"]


def object_height_prior(
    z_m: np.ndarray,
    fused_object_id: np.ndarray,
    fused_z_m: np.ndarray,
    query_object_id: np.ndarray,
    sigma_m: float,
    floor: float,
) -> np.ndarray:
    """(n, n_z) prior weights over the z grid for n queried returns.

    Row i is the kernel density (Gaussian, std `sigma_m`) of the fused heights of the
    object `query_object_id[i]`, scaled to a maximum of 1, plus `floor`; all ones where
    that object has no fused height.

    Args:
        z_m: (n_z,) height grid [m].
        fused_object_id, fused_z_m: (k,) object and height [m] of each fused point.
        query_object_id: (n,) object of each queried return.
        sigma_m: kernel std [m] (> 0).
        floor: weight added everywhere (>= 0): how much a height the object's own
            points never showed can still win.
    """
    if sigma_m <= 0 or floor < 0:
        raise ValueError(f"sigma_m must be > 0 and floor >= 0, got {sigma_m}, {floor}")
    z = np.asarray(z_m, dtype=np.float64)
    fo = np.asarray(fused_object_id, dtype=np.int64).reshape(-1)
    fz = np.asarray(fused_z_m, dtype=np.float64).reshape(-1)
    qo = np.asarray(query_object_id, dtype=np.int64).reshape(-1)
    out = np.ones((qo.size, z.size))
    ok = np.isfinite(fz)
    fo, fz = fo[ok], fz[ok]
    if fo.size == 0 or qo.size == 0:
        return out
    objects, inverse = np.unique(fo, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    kernel = np.exp(-0.5 * ((z[None, :] - fz[order, None]) / sigma_m) ** 2)
    starts = np.flatnonzero(np.r_[True, np.diff(inverse[order]) != 0])
    density = np.add.reduceat(kernel, starts, axis=0)
    density /= density.max(axis=1, keepdims=True)
    pos = np.clip(np.searchsorted(objects, qo), 0, objects.size - 1)
    has = objects[pos] == qo
    out[has] = density[pos[has]] + floor
    return out
