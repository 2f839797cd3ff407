"""Dense submaps on real simulated images: frames between keyframes take the keyframe
objects they see again and get heights from the keyframe-learnt class models, on the
true surface (`sonarmap.stages.submaps.mapping.frame_points`, `sonarmap.stages.submaps.transfer`)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from test_infer import real_stage_tables

from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.schemas.submaps import SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS
from sonarmap.sim.config import MissionConfig, SimConfig
from sonarmap.sim.dataset import simulate
from sonarmap.sim.scene import load_scene
from sonarmap.stages.features.stage import FeaturesConfig
from sonarmap.stages.fuse.stage import FuseConfig
from sonarmap.stages.infer.stage import InferConfig, learn_and_infer
from sonarmap.stages.kernels.frame_features import keyframe_features
from sonarmap.stages.kernels.fusion import fuse_keyframe, sonar_offset
from sonarmap.stages.kernels.geometry import se3_from_pose as pose_to_matrix
from sonarmap.stages.kernels.point_tables import points_table
from sonarmap.stages.kernels.sightings import object_feature_rows
from sonarmap.stages.submaps.mapping import frame_points
from sonarmap.stages.submaps.transfer import KeyframeObjectPoints, transfer_objects
from tests.fixtures import keyframe_indices

REPO = Path(__file__).resolve().parents[1]


def test_frames_between_keyframes_are_inferred_on_the_true_wall() -> None:
    config = SimConfig(mission=MissionConfig(n_goals=4, duration_s=150.0))
    run = simulate(load_scene(REPO / "configs" / "scenes" / "quay.yaml"), config, 0)
    kf_frames = keyframe_indices(run, 4.0)
    objects, links, features, fused = real_stage_tables(run, 4.0)
    icfg = InferConfig()
    _, _, states = learn_and_infer(objects, links, features, fused, icfg)
    horizontal = features.filter(pc.equal(features.column("sonar"), "horizontal"))
    rows = object_feature_rows(objects, links, horizontal, fused)
    class_of = dict(
        zip(
            objects.column("object_id").to_pylist(),
            objects.column("class_name").to_pylist(),
            strict=True,
        )
    )
    sensors = {s: {"T_base_sonar": m.tolist()} for s, m in run.T_base_sonar.items()}
    T_h_v = sonar_offset(sensors)

    def T_world_sonar(i: int) -> np.ndarray:
        f = run.frame(i)
        return pose_to_matrix(f.gt_pose) @ f.T_base_sonar["horizontal"]

    parts, frame_T = [], {}
    for k, (start, end) in enumerate(itertools.pairwise(kf_frames)):
        sel = rows["keyframe_id"] == k
        r, t = rows["range_m"][sel], rows["bearing_rad"][sel]
        kf_objects = KeyframeObjectPoints(
            np.c_[r * np.cos(t), r * np.sin(t)], rows["object_id"][sel]
        )
        for i in range(start + 1, end, 3):  # every third pair between the keyframes
            frame_id = len(frame_T)
            frame_T[frame_id] = T_world_sonar(i)
            f = run.frame(i)
            image = KeyframeImages(frame_id, f.t_ns, f.horizontal, f.vertical)
            feats = keyframe_features(image, FeaturesConfig())
            feats["is_horizontal"] = feats["sonar_index"] == 0
            is_h = feats["is_horizontal"]
            fu = fuse_keyframe(image, feats, T_h_v, FuseConfig())
            T = np.linalg.inv(T_world_sonar(kf_frames[k])) @ frame_T[frame_id]
            oid = transfer_objects(
                feats["range_m"][is_h], feats["angle_rad"][is_h], [T], [kf_objects],
                eps_m=0.25, min_samples=2, min_features=10, match_radius_m=0.25,
            )  # fmt: skip
            parts += frame_points(frame_id, k, feats, is_h, oid, fu, class_of, states, icfg, {})
    points = points_table(parts, SUBMAP_POINTS_SCHEMA, SUBMAP_POINTS_SORT_KEYS)

    def world(table: pa.Table) -> np.ndarray:
        xyz = np.c_[[table.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")]].T
        fid = table.column("frame_id").to_numpy()
        out = np.empty_like(xyz)
        for j in np.unique(fid):
            out[fid == j] = xyz[fid == j] @ frame_T[int(j)][:3, :3].T + frame_T[int(j)][:3, 3]
        return out

    source = points.column("source")
    fused_pts = points.filter(pc.equal(source, "fused"))
    inferred = points.filter(pc.equal(source, "inferred"))
    assert len(frame_T) >= 10 and inferred.num_rows > 5 * fused_pts.num_rows > 0
    assert set(inferred.column("class_name").to_pylist()) == {"seawall"}
    d_fused = run.world.distance(world(fused_pts))
    d_inferred = run.world.distance(world(inferred))
    # as on keyframes (tests/test_infer_structure.py): close to the fused points' error
    assert np.median(d_inferred) <= 1.5 * np.median(d_fused)
    assert np.median(d_inferred) <= 0.25
