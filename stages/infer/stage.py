"""Stage `infer`: object-class Bayesian height models and MAP prediction of 3D
structure for 2D-only returns (paper Sec. IV.D-E, Eq. 7-9).

Per keyframe, in keyframe-id order (keyframe ids are assigned in time order by the
keyframes stage), and per inferred class (config `classes`, default both piling
classes):

1. Update (Sec. IV.D, Eq. 7): every object of the class with fused 3D points is put
   into its object frame (origin: minimum range, median bearing of all its 2D
   returns; `sonarmap.stages.kernels.object_frame`), registered to the class reference frame with ICP
   (the first such object defines it) and, if the registration succeeded, its fused
   points update the class `HeightModel` at their (registered) range/bearing with
   their Cartesian height z. One model update per class and keyframe, so fused points
   sharing a cell within the keyframe form a max-mixture.
2. Query (Sec. IV.E, Eq. 8-9): once a class model has been updated, every object of
   the class is registered to the reference frame (the reference cloud is not
   changed) and each of its 2D-only returns (horizontal features without a fused
   point) gets the MAP height over z <= 0 and over z > 0, each kept if its posterior
   probability exceeds `confidence_threshold`. A return thus yields 0, 1 or 2 points,
   converted to the sonar frame with paper Eq. 1.

Beyond the paper: seawalls (default on) and trusses and hulls (when listed), whose
objects rarely fit in one image, use per-beam leading-edge frames instead of one ICP-registered class frame
(`sonarmap.stages.kernels.beam_frame`, `InferConfig.frame_kinds`), updated and queried in one vectorised
pass per class and keyframe, with a Dirichlet-count height model (`beam_update_rule
"mixture"`: a cell of a wall returns from above and below at once, which Eq. 7's
product would collapse to one mode). Optionally (`beam_object_prior_m`) each object's own
fused heights in the image, as a kernel density, multiply the class posterior of its 2D-only
returns (`sonarmap.stages.kernels.object_prior`; docs/decisions/015-per-object-height-prior.md).
`infer.classes` set to the two piling classes is the paper's behaviour.

With `query_model="final"` (not in the paper) all updates come first, over every
keyframe, and every keyframe is then queried with the models as the last update left
them: the models stage `submaps` queries its frames with. A sighting from before its
class's first update then predicts too, and every sighting is registered to the final
reference cloud.

Output `stats` (`stats.json`): what each class loses at each step (`Funnel`).

Output `points`: the fused points of every classified object (any class, with its
object id and class name, `source="fused"`) and the inferred points
(`source="inferred"`), schema `sonarmap.schemas.points.POINTS_SCHEMA`. Fused points that
belong to no object are not repeated here (they are in `fuse.fused`).

Outputs `class_reference` and `class_cells` (`sonarmap.schemas.class_models`): every class's
reference cloud and height-model cells after the last keyframe, which stage `submaps`
queries its frames with (`sonarmap.stages.kernels.class_models`).

Deviations from the paper / original code (deliberate, see the module docstrings of
`sonarmap.stages.kernels.height_model` and `.object_frame`): metric object frames shared by 2D and 3D points,
a sparse unbounded cell grid, an explicit confidence threshold, failed ICP skipped,
and predictions whose elevation falls outside the horizontal sonar's vertical
aperture (`max_elevation_deg`) are dropped, since no return can come from there.

Deviation, `range_axis="height_equivalent"` (default): the model's range axis is
sign(u) sqrt(|u^2 + 2 R0 u|) (R0: the sighting's own minimum range), not the offset u,
because with u one model mixes a piling's heights seen from different distances;
measurements in docs/decisions/001-height-equivalent-range-axis.md.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from sonarmap.schemas.classes import DEFAULT_TABLE
from sonarmap.stages.infer import STAGE
from sonarmap.stages.infer.config import InferConfig
from sonarmap.stages.kernels.class_models import (
    ClassState,
    class_model_tables,
    inferred_classes,
    new_class_states,
)
from sonarmap.stages.kernels.class_query import (
    FUNNEL_STEPS,
    Funnel,
    borrowed_sightings,
    register_and_query,
    update_and_query_beam_class,
    update_object_class,
)
from sonarmap.stages.kernels.point_tables import points_table, tag_points
from sonarmap.stages.kernels.sightings import column, object_feature_rows
from sonarmap.stages.kernels.sightings import sightings as _sightings

__all__ = [
    "STAGE",
    "InferConfig",
    "infer_mission",
    "infer_points",
    "learn_and_infer",
]

logger = logging.getLogger(__name__)

_FUSED_COLUMNS = ("range_m", "bearing_rad", "elevation_rad", "x_m", "y_m", "z_m", "confidence")


def infer_points(
    objects: pa.Table,
    object_features: pa.Table,
    features: pa.Table,
    fused: pa.Table,
    config: InferConfig,
) -> pa.Table:
    """The points of `infer_mission` (its loss accounting dropped)."""
    return infer_mission(objects, object_features, features, fused, config)[0]


def infer_mission(
    objects: pa.Table,
    object_features: pa.Table,
    features: pa.Table,
    fused: pa.Table,
    config: InferConfig,
) -> tuple[pa.Table, dict[str, Any]]:
    """Run the update/query loop over all keyframes; see the module docstring.

    Args:
        objects: classify.objects (keyframe_id, object_id, class_name, ...).
        object_features: classify.object_features (keyframe_id, object_id, feature_id).
        features: features.features (keyframe_id, feature_id, range_m, angle_rad, ...).
        fused: fuse.fused (keyframe_id, horizontal feature id, range_m, bearing_rad,
            elevation_rad, x_m, y_m, z_m, confidence), sonar frame.
        config: stage config.

    Returns:
        Table with `POINTS_SCHEMA`, sorted by (keyframe_id, object_id, source,
        range_m, bearing_rad, z_m), and the loss accounting (`stats.json`):
        {"horizontal_returns", "clustered_returns", "classes": {class: {step: count}
        (`Funnel`), "frame": kind, "model_cells": int for inferred classes}}.
    """
    table, stats, _ = learn_and_infer(objects, object_features, features, fused, config)
    return table, stats


def learn_and_infer(
    objects: pa.Table,
    object_features: pa.Table,
    features: pa.Table,
    fused: pa.Table,
    config: InferConfig,
) -> tuple[pa.Table, dict[str, Any], dict[str, ClassState]]:
    """`infer_mission`, plus every class's reference frame and height model as they
    stand after the last keyframe (output `class_*`, what stage `submaps` queries its
    frames with; queries change neither the reference clouds nor the height models)."""
    states = new_class_states(config)
    funnels: dict[str, Funnel] = {}
    horizontal = features
    if "sonar" in features.column_names:
        horizontal = features.filter(pc.equal(features.column("sonar"), "horizontal"))
    # One vectorised join for the mission; each keyframe is a slice of its rows.
    rows = object_feature_rows(objects, object_features, horizontal, fused)
    fused_cols = {c: column(fused, c, "fused").astype(np.float64) for c in _FUSED_COLUMNS}
    kf = rows["keyframe_id"]
    starts = np.flatnonzero(np.r_[True, kf[1:] != kf[:-1]]) if kf.size else np.empty(0, int)
    bounds = np.r_[starts, kf.size]
    keyframes = [
        (int(kf[start]), slice(int(start), int(bounds[i + 1]))) for i, start in enumerate(starts)
    ]
    mission = _Mission(rows, fused_cols, states, config, funnels)
    if config.query_model == "online":
        parts = [p for kf_id, part in keyframes for p in mission.update_and_query(kf_id, part)]
    else:
        parts = [p for kf_id, part in keyframes for p in mission.update(kf_id, part)]
        parts += [p for kf_id, part in keyframes for p in mission.query(kf_id, part)]
    sonar = features.column("sonar") if "sonar" in features.column_names else None
    stats: dict[str, Any] = {
        "horizontal_returns": int(
            features.num_rows
            if sonar is None
            else pc.sum(pc.equal(sonar, "horizontal")).as_py() or 0
        ),
        "clustered_returns": int(object_features.num_rows),
        "classes": {c: dict(f.counts) for c, f in sorted(funnels.items())},
    }
    for c, state in states.items():
        stats["classes"].setdefault(c, dict.fromkeys(FUNNEL_STEPS, 0))
        stats["classes"][c].update(frame=config.frame_kind(c), model_cells=state.model.n_cells)
    return points_table(parts), stats, states


@dataclass(frozen=True)
class _Mission:
    """What every keyframe's update and query read: the mission's joined rows (each
    keyframe a slice of them), the fused columns, and the classes' states and funnels,
    which they change."""

    rows: dict[str, np.ndarray]
    fused_cols: dict[str, np.ndarray]
    states: dict[str, ClassState]
    config: InferConfig
    funnels: dict[str, Funnel]

    def update_and_query(self, keyframe_id: int, of_keyframe: slice) -> list[dict[str, Any]]:
        """Update (Eq. 7) then query (Eq. 8-9) every inferred class with one keyframe."""
        sightings = _sightings(self.rows, of_keyframe, self.fused_cols)
        parts = _fused_points(keyframe_id, sightings, self.fused_cols, self.funnels)
        for c in inferred_classes(self.config):
            transforms = None
            if self.config.frame_kind(c) != "beam":
                transforms = self.update_objects(c, sightings)
            parts += self.query_class(c, keyframe_id, sightings, True, transforms)
        return parts

    def update(self, keyframe_id: int, of_keyframe: slice) -> list[dict[str, Any]]:
        """`query_model="final"`, first pass: the keyframe's fused points, and Eq. 7 for
        every inferred class; nothing is queried yet."""
        sightings = _sightings(self.rows, of_keyframe, self.fused_cols)
        parts = _fused_points(keyframe_id, sightings, self.fused_cols, self.funnels)
        for c in inferred_classes(self.config):
            if self.config.frame_kind(c) == "beam":
                of_class = [s for s in sightings if s.class_name == c]
                funnel = self.funnels.setdefault(c, Funnel())
                update_and_query_beam_class(
                    self.states[c], of_class, self.config, funnel, query=False
                )
            else:
                self.update_objects(c, sightings)
        return parts

    def update_objects(self, c: str, sightings: list) -> dict[int, np.ndarray]:
        """Eq. 7 for object-frame class c with a keyframe's sightings; its registrations."""
        of_class = [s for s in sightings if s.class_name == c]
        transforms = update_object_class(self.states[c], of_class, self.config.range_axis)
        self.funnels.setdefault(c, Funnel()).counts["updated_objects"] += len(transforms)
        return transforms

    def query(self, keyframe_id: int, of_keyframe: slice) -> list[dict[str, Any]]:
        """`query_model="final"`, second pass: Eq. 8-9 with the models after the last
        update, every sighting registered to its class's final reference (as stage
        `submaps` does)."""
        sightings = _sightings(self.rows, of_keyframe, self.fused_cols)
        parts = []
        for c in inferred_classes(self.config):
            parts += self.query_class(c, keyframe_id, sightings, False)
        return parts

    def query_class(
        self,
        c: str,
        keyframe_id: int,
        sightings: list,
        update_beam: bool,
        transforms: dict[int, np.ndarray] | None = None,
    ) -> list[dict[str, Any]]:
        """Eq. 8-9 for class c's sightings in a keyframe and for the objects borrowing its
        model; a beam-frame class is also updated here when `update_beam` (one vectorised
        pass), an object-frame class reuses its update's registrations (`transforms`)."""
        state, config = self.states[c], self.config
        funnel = self.funnels.setdefault(c, Funnel())
        of_class = [s for s in sightings if s.class_name == c]
        if config.frame_kind(c) == "beam":
            found = update_and_query_beam_class(state, of_class, config, funnel, update=update_beam)
        elif not state.model.updated:
            return []
        else:
            found = register_and_query(state, of_class, config, funnel, transforms)
        parts = []
        if found is not None:
            parts.append(tag_points(found[0], keyframe_id, found[1], c, "inferred"))
        for borrower, routed in borrowed_sightings(c, sightings, config):
            # The points keep the borrower's class and the model is not updated; an
            # object-frame lender's borrowers must register to its reference first.
            lent_funnel = self.funnels.setdefault(borrower, Funnel())
            if config.frame_kind(c) == "beam":
                lent = update_and_query_beam_class(state, routed, config, lent_funnel, update=False)
            else:
                lent = register_and_query(state, routed, config, lent_funnel)
            if lent is not None:
                parts.append(tag_points(lent[0], keyframe_id, lent[1], borrower, "inferred"))
        return parts


def _fused_points(
    keyframe_id: int,
    sightings: list,
    fused_cols: dict[str, np.ndarray],
    funnels: dict[str, Funnel],
) -> list[dict[str, Any]]:
    """Every sighting's fused points, tagged with its class; counted in its funnel."""
    parts = []
    for s in sightings:
        pts = {c: v[s.fused_rows] for c, v in fused_cols.items()}
        parts.append(tag_points(pts, keyframe_id, s.object_id, s.class_name, "fused"))
        funnel = funnels.setdefault(s.class_name, Funnel())
        funnel.counts["objects"] += 1
        funnel.counts["returns"] += s.range_m.size
        funnel.counts["fused_returns"] += int(s.is_fused.sum())
    return parts


def _run(config: InferConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    config = config.with_table(inputs.get("config.classes", DEFAULT_TABLE))
    points, stats, states = learn_and_infer(
        inputs["classify.objects"],
        inputs["classify.object_features"],
        inputs["features.features"],
        inputs["fuse.fused"],
        config,
    )
    reference, cells = class_model_tables(states)
    return {"points": points, "stats": stats, "class_reference": reference, "class_cells": cells}
