"""Update and query of one class's height model with one keyframe or frame (paper
Eq. 7-9), shared by stage `infer` (keyframes: update, then query) and stage `submaps`
(its frames: query only, the models as infer left them).

Object-frame classes (pilings) register each sighting into the class's reference frame
(`sonarmap.stages.kernels.object_frame`), update the model with its fused returns (Eq. 7) and query
its 2D-only returns (Eq. 8-9); beam-frame classes (walls, trusses, hulls) put every
return into its per-beam leading-edge frame (`sonarmap.stages.kernels.beam_frame`) instead, in one
vectorised pass per keyframe. `Funnel` counts what each step loses (`stats.json`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from sonarmap.schemas.classes import UNKNOWN_CLASS
from sonarmap.stages.kernels.beam_frame import beam_anchor_range, beam_model_coords
from sonarmap.stages.kernels.class_models import ClassModelSettings, ClassState
from sonarmap.stages.kernels.fallback_model import CoarseFallbackModel
from sonarmap.stages.kernels.geometry import polar_to_xyz, se2_apply
from sonarmap.stages.kernels.height_model import HeightQuery
from sonarmap.stages.kernels.object_frame import ObjectOrigin
from sonarmap.stages.kernels.object_prior import object_height_prior
from sonarmap.stages.kernels.sightings import Sighting

logger = logging.getLogger(__name__)

__all__ = [
    "FUNNEL_STEPS",
    "Funnel",
    "borrowed_sightings",
    "model_coords",
    "predicted_points",
    "query_object_sightings",
    "register_and_query",
    "update_and_query_beam_class",
    "update_object_class",
]


FUNNEL_STEPS = (
    "objects",
    "returns",
    "fused_returns",
    "updated_objects",
    "registered_objects",
    "queried_returns",
    "seen_returns",
    "predicted_returns",
    "inferred_points",
)


@dataclass
class Funnel:
    """What one class loses at each step of inference (counts over the mission).

    objects / returns / fused_returns: sightings of the class, their 2D returns and
    those with a fused 3D point; updated_objects: sightings whose fused points updated
    the model; registered_objects: sightings put into the reference frame (object
    frames: ICP succeeded; beam frames: all, once the model has data); queried_returns:
    their 2D-only returns; seen_returns: those whose model cell has data;
    predicted_returns: those with a confident height inside the aperture;
    inferred_points: the points they gave (0-2 each).
    """

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FUNNEL_STEPS, 0))

    def count_query(self, n_queried: int, q: HeightQuery, of_return: np.ndarray) -> None:
        self.counts["queried_returns"] += n_queried
        self.counts["seen_returns"] += int(np.count_nonzero(q.seen))
        self.counts["predicted_returns"] += int(np.unique(of_return).size)
        self.counts["inferred_points"] += int(of_return.size)


def model_coords(uv_ref: np.ndarray, origin: ObjectOrigin, range_axis: str) -> np.ndarray:
    """Model-cell coordinates of (n, 2) reference-frame points of a sighting.

    "offset": (u, v) as is (the paper). "height_equivalent": u is replaced by
    sign(u) sqrt(|u^2 + 2 R0 u|), R0 the sighting's own minimum range: the height at
    which a vertical surface through the object's nearest point returns at range
    R0 + u, so one structure fills the same cells whatever distance it is seen from.
    """
    if range_axis == "offset":
        return uv_ref
    u = uv_ref[:, 0]
    s = np.sign(u) * np.sqrt(np.abs(u * u + 2.0 * origin.range_m * u))
    return np.stack([s, uv_ref[:, 1]], axis=1)


def update_object_class(
    state: ClassState, sightings: list[Sighting], range_axis: str
) -> dict[int, np.ndarray]:
    """Eq. 7 for one class and keyframe; returns successful registrations by object id."""
    uv, z, transforms = [], [], {}
    for s in sightings:
        if s.fused_z_m.size == 0:
            continue
        reg = state.frame.add_sighting(s.uv_m, s.origin)
        if not reg.ok:
            logger.debug("object %d: registration failed, update skipped", s.object_id)
            continue
        if reg.reseeded:  # a new reference frame: what the old one learned does not apply
            state.model = state.empty_model()
            uv, z, transforms = [], [], {}
        transforms[s.object_id] = reg.T_ref_obj
        uv.append(model_coords(se2_apply(reg.T_ref_obj, s.fused_uv_m), s.origin, range_axis))
        z.append(s.fused_z_m)
    if uv:
        state.model.update(np.vstack(uv), np.concatenate(z))
    return transforms


def predicted_points(
    q: HeightQuery, range_m: np.ndarray, bearing_rad: np.ndarray, config: ClassModelSettings
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Points of the MAP heights of n queried returns (0-2 each) and, per point, the
    index of its return; heights outside +-max_elevation_deg are dropped.

    A height z at range R gives the elevation phi = asin(z / R), and the point is paper
    Eq. 1 of (R, theta, phi) in the horizontal sonar frame."""
    n = range_m.size
    r = np.tile(range_m, 2)
    z = np.concatenate([q.z_low_m, q.z_high_m])
    conf = np.concatenate([q.conf_low, q.conf_high])
    elevation = np.arcsin(np.clip(z / np.maximum(r, 1e-9), -1.0, 1.0))
    keep = np.isfinite(z) & (np.abs(elevation) <= np.deg2rad(config.max_elevation_deg))
    r, bearing, elevation = r[keep], np.tile(bearing_rad, 2)[keep], elevation[keep]
    x, y, z = np.ascontiguousarray(polar_to_xyz(r, bearing, elevation).T)
    pts = {
        "range_m": r,
        "bearing_rad": bearing,
        "elevation_rad": elevation,
        "x_m": x,
        "y_m": y,
        "z_m": z,
        "confidence": conf[keep],
    }
    return pts, np.flatnonzero(keep) % max(n, 1)


def query_object_sightings(
    state: ClassState,
    registered: list[tuple[Sighting, np.ndarray]],
    config: ClassModelSettings,
    funnel: Funnel,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Eq. 8-9 for the 2D-only returns of a keyframe's registered sightings of one class.

    Args:
        registered: (sighting, T_ref_obj) pairs.

    Returns:
        (points, object id per point): 0-2 points per return, one model query for all.
    """
    only2d = [~s.is_fused for s, _ in registered]
    uv = [
        model_coords(se2_apply(T, s.uv_m[m]), s.origin, config.range_axis)
        for (s, T), m in zip(registered, only2d, strict=True)
    ]
    q = state.model.query(np.vstack(uv), config.confidence_threshold)
    r = np.concatenate([s.range_m[m] for (s, _), m in zip(registered, only2d, strict=True)])
    t = np.concatenate([s.bearing_rad[m] for (s, _), m in zip(registered, only2d, strict=True)])
    oid = np.repeat([s.object_id for s, _ in registered], [int(m.sum()) for m in only2d])
    pts, of_return = predicted_points(q, r, t, config)
    funnel.count_query(r.size, q, of_return)
    return pts, oid[of_return].astype(np.int64)


def register_and_query(
    state: ClassState,
    sightings: list[Sighting],
    config: ClassModelSettings,
    funnel: Funnel,
    transforms: dict[int, np.ndarray] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray] | None:
    """Eq. 8-9 for object-frame sightings: each is registered to the class reference
    frame (or takes its registration from `transforms`, the update's), failed ICP is
    skipped, and the rest are queried together. None when nothing registered."""
    known = transforms or {}
    registered = []
    for s in sightings:
        T = known.get(s.object_id)
        if T is None:
            reg = state.frame.register(s.uv_m)
            if not reg.ok:
                continue
            T = reg.T_ref_obj
        registered.append((s, T))
    funnel.counts["registered_objects"] += len(registered)
    if not registered:
        return None
    return query_object_sightings(state, registered, config, funnel)


def update_and_query_beam_class(
    state: ClassState,
    sightings: list[Sighting],
    config: ClassModelSettings,
    funnel: Funnel,
    update: bool = True,
    query: bool = True,
) -> tuple[dict[str, np.ndarray], np.ndarray] | None:
    """Update (Eq. 7) then query (Eq. 8-9) one beam-frame class with one keyframe.

    All sightings of the class in the keyframe share one vectorised pass: every return
    is put into its beam frame (`sonarmap.stages.kernels.beam_frame`), the fused ones update the class
    model (unless `update` is False: query only), the 2D-only ones are queried (unless
    `query` is False: update only). Returns (points, object id per point), or None before
    the model has data or without a query.
    """
    if not sightings:
        return None
    r = np.concatenate([s.range_m for s in sightings])
    oid = np.concatenate([np.full(s.range_m.size, s.object_id, np.int64) for s in sightings])
    fused = np.concatenate([s.is_fused for s in sightings])
    anchor = beam_anchor_range(
        oid, np.concatenate([s.beam for s in sightings]), r, config.beam_gap_m
    )
    coords = beam_model_coords(r, anchor, config.range_axis, config.beam_range_cell_m)
    if update and fused.any():
        state.model.update(coords[fused], np.concatenate([s.fused_z_m for s in sightings]))
        funnel.counts["updated_objects"] += len(
            {s.object_id for s in sightings if s.is_fused.any()}
        )
    if not query or not state.model.updated:
        return None
    funnel.counts["registered_objects"] += len(sightings)
    prior = None
    if config.beam_object_prior_m is not None:
        prior = object_height_prior(
            state.model.fine.z_m
            if isinstance(state.model, CoarseFallbackModel)
            else state.model.z_m,
            oid[fused],
            np.concatenate([s.fused_z_m for s in sightings]),
            oid[~fused],
            config.beam_object_prior_m,
            config.beam_object_prior_floor,
        )
    q = state.model.query(coords[~fused], config.confidence_threshold, prior)
    bearing = np.concatenate([s.bearing_rad for s in sightings])[~fused]
    pts, of_return = predicted_points(q, r[~fused], bearing, config)
    funnel.count_query(int((~fused).sum()), q, of_return)
    return pts, oid[~fused][of_return]


def borrowed_sightings(
    lender: str, sightings: list[Sighting], config: ClassModelSettings
) -> list[tuple[str, list[Sighting]]]:
    """(borrowing class, its sightings) that take heights from `lender`'s model, query
    only: 'unknown' objects whose arg-max class it is (`unknown_argmax_classes`) and
    the objects of every class that borrows it (`borrowed_models`). From a beam-frame
    lender only objects whose returns span at least `borrow_min_extent_m` borrow
    (extended structure, the beam frame's premise); an object-frame lender's borrowers
    must register to its reference instead, which the caller checks."""

    def extended(s: Sighting) -> bool:
        return config.frame_kind(lender) != "beam" or s.extent_m >= config.borrow_min_extent_m

    routes = []
    if lender in config.unknown_argmax_classes:
        routes.append(
            (
                UNKNOWN_CLASS,
                [
                    s
                    for s in sightings
                    if s.class_name == UNKNOWN_CLASS
                    and s.argmax_class_name == lender
                    and extended(s)
                ],
            )
        )
    for borrower in sorted(b for b, c in config.borrowed_models.items() if c == lender):
        routes.append(
            (borrower, [s for s in sightings if s.class_name == borrower and extended(s)])
        )
    return [(b, routed) for b, routed in routes if routed]
