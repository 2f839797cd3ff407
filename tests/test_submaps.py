"""Dense submaps (stage `submaps`, issue 21): which pairs become frames and where they sit,
objects handed over from keyframes, honest keys through the CLI, frames on the true
surface, frames that move with their keyframe, byte-identical reruns."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation
from test_voxelize import T_BASE_SONAR, fused_table, points_table, poses_table
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.model import plan_training, training_datasets
from sonarmap.pipeline.training.model_cache import model_cache
from sonarmap.schemas.submaps import REL_POSE_COLUMNS, SUBMAP_FRAMES_SCHEMA, SUBMAP_POINTS_SCHEMA
from sonarmap.stages.kernels.geometry import rpy_from_matrix as rpy_from_rotation
from sonarmap.stages.kernels.geometry import se3_from_pose as pose_to_matrix
from sonarmap.stages.kernels.poses import pose_matrix
from sonarmap.stages.submaps.frames import submap_frame_rows
from sonarmap.stages.submaps.transfer import KeyframeObjectPoints, transfer_objects
from sonarmap.stages.submaps.workers import worker_count
from sonarmap.stages.voxelize.stage import build_map

POSE = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
UPSTREAM = ("keyframes", "features", "fuse", "classify", "slam", "infer")
DOWNSTREAM = ("submaps", "voxelize", "evaluate")


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    xyz = rng.uniform(-20, 20, (n, 3))
    rpy = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    return np.c_[xyz, rpy]


# --- a. which pairs become frames ---------------------------------------------------------


def reference_frames(kf_ping: list[int], pings: list[int], stride: int) -> list[tuple[int, int]]:
    """Independent restatement: (ping, owner keyframe) of every stride-th pair after each
    keyframe, counting the pairs between it and the next keyframe."""
    out = []
    for k, start in enumerate(kf_ping):
        end = kf_ping[k + 1] if k + 1 < len(kf_ping) else max(pings) + 1
        between = [p for p in pings if start < p < end]
        out += [(p, k) for p in between[stride - 1 :: stride]] if stride else []
    return out


@pytest.mark.parametrize("stride", [0, 1, 2, 3])
def test_frames_are_every_stride_th_pair_after_each_keyframe(stride: int) -> None:
    rng = np.random.default_rng(stride)
    pings = [p for p in range(2, 30) if p not in (12, 13)]  # 0-1 unposed, 12-13 unpaired
    kf_ping = [4, 9, 10, 21]  # nothing before ping 4 is a frame; keyframe 1 owns none
    pose, gt = random_poses(rng, len(pings)), random_poses(rng, len(pings))
    h_t = np.arange(32, dtype=np.int64) * 500_000_000
    v_t = h_t + 7
    v_idx = np.asarray(pings) + 1
    frames = submap_frame_rows(kf_ping, pings, v_idx, h_t, v_t, pose, gt, stride)
    want = reference_frames(kf_ping, pings, stride)
    got_ping = frames.column("ping_index_horizontal").to_pylist()
    assert list(zip(got_ping, frames.column("keyframe_id").to_pylist(), strict=True)) == want
    assert frames.column("frame_id").to_pylist() == list(range(len(want)))
    if stride == 1:
        assert len(want) == len([p for p in pings if p > kf_ping[0] and p not in kf_ping])
    rows = np.searchsorted(pings, got_ping)
    assert frames.column("t_ns").to_pylist() == h_t[got_ping].tolist()
    assert frames.column("ping_index_vertical").to_pylist() == v_idx[rows].tolist()
    assert frames.column("t_vertical_ns").to_pylist() == v_t[v_idx[rows]].tolist()
    got_pose = np.stack([frames.column(c).to_numpy() for c in POSE], axis=1).reshape(-1, 6)
    got_gt = np.stack([frames.column(f"gt_{c}").to_numpy() for c in POSE], axis=1).reshape(-1, 6)
    np.testing.assert_array_equal(got_pose, pose[rows])
    np.testing.assert_array_equal(got_gt, gt[rows])
    # T_world_kf @ T_kf_frame is the frame's own dead-reckoning pose (sim's independent matrices).
    rel = np.stack([frames.column(c).to_numpy() for c in REL_POSE_COLUMNS], axis=1)
    owner_rows = np.searchsorted(pings, np.asarray(kf_ping)[frames.column("keyframe_id")])
    for r, o, q in zip(rel, owner_rows, rows, strict=True):
        composed = pose_to_matrix(pose[o]) @ pose_to_matrix(r)
        np.testing.assert_allclose(composed, pose_to_matrix(pose[q]), atol=1e-9)


def test_pose_matrix_round_trips_and_frames_without_truth_have_null_truth() -> None:
    rng = np.random.default_rng(4)
    poses = random_poses(rng, 50)
    T = pose_matrix(poses)
    np.testing.assert_allclose(T, np.stack([pose_to_matrix(p) for p in poses]), atol=1e-12)
    np.testing.assert_allclose(rpy_from_rotation(T[:, :3, :3]), poses[:, 3:], atol=1e-9)
    pings = list(range(10))
    h_t = np.arange(10, dtype=np.int64)
    frames = submap_frame_rows([0, 5], pings, pings, h_t, h_t, poses[:10], None, 2)
    assert frames.column("ping_index_horizontal").to_pylist() == [2, 4, 7, 9]
    assert frames.column("gt_x_m").null_count == frames.num_rows == 4
    assert submap_frame_rows([], pings, pings, h_t, h_t, poses[:10], None, 1).num_rows == 0


# --- b. objects handed over from the keyframe ---------------------------------------------


def polar(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.hypot(xy[:, 0], xy[:, 1]), np.arctan2(xy[:, 1], xy[:, 0])


def se2(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:2, 3] = (x, y)
    return T


def arc(centre: tuple[float, float], n: int, radius: float = 0.3) -> np.ndarray:
    a = np.linspace(-np.pi / 2, np.pi / 2, n)
    return np.c_[centre[0] - radius * np.cos(a), centre[1] + radius * np.sin(a)]


def in_frame(T_kf_frame: np.ndarray, xy_kf: np.ndarray) -> np.ndarray:
    """Keyframe-sonar-plane points seen from the frame's sonar."""
    inv = np.linalg.inv(T_kf_frame)
    return xy_kf @ inv[:2, :2].T + inv[:2, 3]


def test_a_cluster_seen_again_takes_the_keyframe_object_and_a_new_one_stays_unassigned() -> None:
    piling, wall = arc((6.0, 1.0), 12), np.c_[np.full(15, 4.0), np.linspace(-3.7, -3.0, 15)]
    objs = KeyframeObjectPoints(np.r_[piling, wall], np.r_[np.full(12, 7), np.full(15, 9)])
    T = se2(0.8, 0.2, 0.05)  # the frame sonar 0.8 m ahead, in the keyframe's sonar frame
    rng = np.random.default_rng(0)
    new = np.c_[rng.uniform(9.0, 9.3, 10), rng.uniform(5.0, 5.3, 10)]  # no keyframe object
    xy = np.r_[in_frame(T, piling[::2]), in_frame(T, wall[1::2]), in_frame(T, new)]
    xy[:-10] += rng.normal(0, 0.01, (len(xy) - 10, 2))
    r, b = polar(xy)
    oid = transfer_objects(r, b, [T], [objs], 0.25, 2, 5, 0.1)
    np.testing.assert_array_equal(oid, np.r_[np.full(6, 7), np.full(7, 9), np.full(10, -1)])
    # The dead-reckoning motion is what lines them up: without it nothing matches.
    assert (transfer_objects(r, b, [np.eye(4)], [objs], 0.25, 2, 5, 0.1) == -1).all()
    # Objects of the next keyframe count too, each through its own transform.
    T_kf_next = se2(-1.2, 0.1, -0.1)  # the next keyframe's sonar in this one's
    other = KeyframeObjectPoints(in_frame(T_kf_next, new), np.full(10, 4))
    T_next_frame = np.linalg.inv(T_kf_next) @ T
    both = transfer_objects(r, b, [T, T_next_frame], [objs, other], 0.25, 2, 5, 0.1)
    np.testing.assert_array_equal(both, np.r_[np.full(6, 7), np.full(7, 9), np.full(10, 4)])


def test_a_cluster_across_two_objects_takes_the_majority_and_noise_takes_none() -> None:
    line = np.c_[np.full(21, 5.0), np.linspace(0.0, 1.0, 21)]
    objs = KeyframeObjectPoints(line, np.where(line[:, 1] <= 0.7, 3, 4))  # 15 vs 6 returns
    lone = np.array([[5.0, 2.0]])  # on no cluster: DBSCAN noise, though next to object 4
    objs2 = KeyframeObjectPoints(np.r_[line, lone], np.r_[objs.object_id, 4])
    r, b = polar(np.r_[line, lone])
    oid = transfer_objects(r, b, [np.eye(4)], [objs2], 0.25, 2, 5, 0.02)
    np.testing.assert_array_equal(oid, np.r_[np.full(21, 3), -1])
    flipped = KeyframeObjectPoints(line, np.where(line[:, 1] <= 0.7, 4, 3))
    r, b = polar(line)
    assert set(transfer_objects(r, b, [np.eye(4)], [flipped], 0.25, 2, 5, 0.02)) == {4}
    assert (transfer_objects(r, b, [np.eye(4)], [objs], 0.25, 2, 30, 0.02) == -1).all()


# --- e. a frame moves with its keyframe ---------------------------------------------------


def submap_tables(rng: np.random.Generator) -> tuple[pa.Table, pa.Table, np.ndarray]:
    owner = np.array([0, 0, 1, 1, 1, 2])
    rel = np.c_[rng.uniform(0.2, 1.8, (6, 2)), rng.uniform(-0.1, 0.1, (6, 4))]
    frames: dict[str, object] = {"frame_id": np.arange(6), "keyframe_id": owner}
    frames.update({c: np.arange(6) for c in ("t_ns", "t_vertical_ns")})
    frames.update({c: np.arange(6) for c in ("ping_index_horizontal", "ping_index_vertical")})
    frames.update({c: rel[:, i] for i, c in enumerate(REL_POSE_COLUMNS)})
    frames.update({c: np.zeros(6) for c in POSE})
    frames.update({f"gt_{c}": pa.nulls(6, pa.float64()) for c in POSE})
    fid = np.repeat(np.arange(6), 15)
    xyz = np.c_[rng.uniform(2, 10, fid.size), rng.uniform(-4, 4, (fid.size, 2))]
    rng_m = np.linalg.norm(xyz, axis=1)
    points = {"frame_id": fid, "keyframe_id": owner[fid], "object_id": np.full(fid.size, -1)}
    points.update(class_name=["none"] * fid.size, source=["fused"] * fid.size, range_m=rng_m)
    points.update(
        bearing_rad=np.arctan2(xyz[:, 1], xyz[:, 0]), elevation_rad=np.arcsin(xyz[:, 2] / rng_m)
    )
    points.update(x_m=xyz[:, 0], y_m=xyz[:, 1], z_m=xyz[:, 2], confidence=np.ones(fid.size))
    return (
        pa.table(frames, schema=SUBMAP_FRAMES_SCHEMA),
        pa.table(points, schema=SUBMAP_POINTS_SCHEMA),
        rel,
    )


def groups(m: pa.Table) -> dict[tuple[int, int], np.ndarray]:
    """World points per (keyframe_id, frame_id), rows in lexicographic order."""
    kf, fid = m.column("keyframe_id").to_numpy(), m.column("frame_id").to_numpy()
    xyz = np.stack([m.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
    out = {}
    for key in sorted(set(zip(kf.tolist(), fid.tolist(), strict=True))):
        p = xyz[(kf == key[0]) & (fid == key[1])]
        out[key] = p[np.lexsort(p.T[::-1])]
    return out


def moved(G: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = p @ G[:3, :3].T + G[:3, 3]
    return q[np.lexsort(q.T[::-1])]


def test_moving_a_keyframe_moves_exactly_its_submap_frames() -> None:
    rng = np.random.default_rng(8)
    kf = np.repeat(np.arange(3), 10)
    xyz = np.c_[rng.uniform(2, 10, 30), rng.uniform(-4, 4, (30, 2))]
    fused, points = fused_table(kf, xyz), points_table(kf[:0], xyz[:0], [], [])
    sub_frames, sub_points, rel = submap_tables(rng)
    poses = np.array(
        [[0.0, 0.0, -2.0, 0.0, 0.0, 0.0], [3.0, 1.0, -2.5, 0.05, -0.03, 0.6], [5, 4, -1.5, 0, 0, 2]]
    )
    before, _ = build_map(
        points, fused, poses_table(poses), T_BASE_SONAR, False, sub_frames, sub_points
    )
    # Eq. 4 extended, with independent matrices: T_world_kf T_kf_frame T_base_sonar p.
    for f, owner in enumerate(sub_frames.column("keyframe_id").to_numpy()):
        T = pose_to_matrix(poses[owner]) @ pose_to_matrix(rel[f]) @ T_BASE_SONAR
        p = np.stack([sub_points.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
        p = p[sub_points.column("frame_id").to_numpy() == f]
        np.testing.assert_allclose(groups(before)[(owner, f)], moved(T, p), atol=1e-9)
    # SLAM moves keyframe 1 by G (a rigid change in the world frame).
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("xyz", [0.02, -0.04, 0.3]).as_matrix()
    G[:3, 3] = (0.7, -1.1, 0.2)
    T1 = G @ pose_to_matrix(poses[1])
    shifted = poses.copy()
    shifted[1] = np.r_[T1[:3, 3], Rotation.from_matrix(T1[:3, :3]).as_euler("xyz")]
    after, _ = build_map(
        points, fused, poses_table(shifted), T_BASE_SONAR, False, sub_frames, sub_points
    )
    old, new = groups(before), groups(after)
    assert old.keys() == new.keys()
    assert [k for k in old if k[1] >= 0] == [(0, 0), (0, 1), (1, 2), (1, 3), (1, 4), (2, 5)]
    for key, p in old.items():
        np.testing.assert_allclose(new[key], moved(G, p) if key[0] == 1 else p, atol=1e-9)


# --- c, d, f: through the CLI on a small simulated mission with true poses ----------------

CONFIG = """
training:
  sets:
    - {{scene: tiny, seed: 11, goals: 3, duration_s: 60}}
  procedural: null
  directory: {training}
train:
  epochs: 1
  min_class_samples: 3
classify:
  mc_passes: 4
slam:
  mode: ground_truth
"""


@dataclass(frozen=True)
class Runs:
    """The runs of one store, in order: each one's {stage: (status, artifact path)}."""

    default: dict[str, tuple[str, Path]]
    stride1: dict[str, tuple[str, Path]]
    default_again: dict[str, tuple[str, Path]]
    radius: dict[str, tuple[str, Path]]
    forced: dict[str, tuple[str, Path]]
    points_bytes: bytes
    config: Path


TWO_WORKERS_FORCED = (
    *("--set", "keyframes.submap_stride=1", "--set", "submaps.workers=2"),
    *("--force", "submaps"),
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    """The training mission mapped five times: stride 0, 1, 0, 1 with another match
    radius, 1 with `submaps` forced and mapped by two worker processes (the mission
    doubles as the model's training set)."""
    root = tmp_path_factory.mktemp("submaps")
    config = root / "config.yaml"
    config.write_text(CONFIG.format(training=root / "training"))
    (dataset,) = training_datasets(load_config(all_stages(), config, (), extra_sections()).training)
    base = ["run", str(dataset), "--config", str(config), "--store", str(root / "store")]
    base.append("--no-figures")  # what the stride changes is the map; the figures follow it

    def run(*args: str) -> dict[str, tuple[str, Path]]:
        result = CliRunner().invoke(app, [*base, *args, "--json", "--quiet"])
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        return {s["stage"]: (s["status"], Path(s["path"])) for s in doc["stages"]}

    default = run()
    stride1 = run("--set", "keyframes.submap_stride=1")
    points_bytes = (stride1["submaps"][1] / "submap_points.parquet").read_bytes()
    return Runs(
        default,
        stride1,
        run(),
        run("--set", "keyframes.submap_stride=1", "--set", "submaps.match_radius_m=0.5"),
        run(*TWO_WORKERS_FORCED),
        points_bytes,
        config,
    )


def statuses(run: dict[str, tuple[str, Path]], names: tuple[str, ...]) -> set[str]:
    return {run[n][0] for n in names}


def test_the_stride_recomputes_submaps_voxelize_evaluate_only(runs: Runs) -> None:
    assert list(runs.default) == [*UPSTREAM, *DOWNSTREAM]
    assert statuses(runs.default, (*UPSTREAM, *DOWNSTREAM)) == {"computed"}
    assert statuses(runs.stride1, UPSTREAM) == {"hit"}
    assert statuses(runs.stride1, DOWNSTREAM) == {"computed"}
    assert all(runs.stride1[n][1] == runs.default[n][1] for n in UPSTREAM)
    assert statuses(runs.default_again, (*UPSTREAM, *DOWNSTREAM)) == {"hit"}
    assert runs.default_again == {n: ("hit", p) for n, (_, p) in runs.default.items()}
    assert statuses(runs.radius, UPSTREAM) == {"hit"}
    assert statuses(runs.radius, DOWNSTREAM) == {"computed"}
    assert len({r["submaps"][1] for r in (runs.default, runs.stride1, runs.radius)}) == 3
    # Nor does the stride reach the classifier's key, even when training follows the run.
    classify = json.loads((runs.stride1["classify"][1] / "manifest.json").read_text())
    for overrides in [(), ("training.follow_run=true", "keyframes.submap_stride=2")]:
        config = load_config(all_stages(), runs.config, overrides, extra_sections())
        key = plan_training(training_datasets(config.training), config, model_cache(config))
        assert key == classify["inputs"]["train.model"]


def test_a_forced_rerun_in_two_worker_processes_writes_the_same_bytes(runs: Runs) -> None:
    # same key (workers are not in it), recomputed, and the same bytes as one process
    assert runs.forced["submaps"] == ("computed", runs.stride1["submaps"][1])
    assert statuses(runs.forced, (*UPSTREAM, "voxelize", "evaluate")) == {"hit"}
    again = (runs.forced["submaps"][1] / "submap_points.parquet").read_bytes()
    assert again == runs.points_bytes and len(again) > 1000
    frames = json.loads((runs.forced["submaps"][1] / "stats.json").read_text())["frames"]
    assert worker_count(2, frames) == 2  # enough frames for both workers to map some


def test_frames_sit_between_keyframes_and_compose_to_their_dead_reckoning(runs: Runs) -> None:
    keyframes = pq.read_table(runs.stride1["keyframes"][1] / "keyframes.parquet")
    frames = pq.read_table(runs.stride1["submaps"][1] / "submap_frames.parquet")
    stats = json.loads((runs.stride1["submaps"][1] / "stats.json").read_text())
    kf_ping = keyframes.column("ping_index_horizontal").to_numpy()
    ping = frames.column("ping_index_horizontal").to_numpy()
    owner = frames.column("keyframe_id").to_numpy()
    assert stats["frames"] == frames.num_rows > 3 * keyframes.num_rows
    assert not np.isin(ping, kf_ping).any() and (np.diff(ping) > 0).all()
    np.testing.assert_array_equal(owner, np.searchsorted(kf_ping, ping) - 1)
    kf_pose = np.stack([keyframes.column(c).to_numpy() for c in POSE], axis=1)[owner]
    rel = np.stack([frames.column(c).to_numpy() for c in REL_POSE_COLUMNS], axis=1)
    fr_pose = np.stack([frames.column(c).to_numpy() for c in POSE], axis=1)
    np.testing.assert_allclose(
        pose_matrix(kf_pose) @ pose_matrix(rel), pose_matrix(fr_pose), atol=1e-9
    )
    assert frames.column("gt_x_m").null_count == 0
    default = pq.read_table(runs.default["submaps"][1] / "submap_frames.parquet")
    assert default.num_rows == 0


def fused_errors(run: dict[str, tuple[str, Path]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame_id, error_m, xyz) of the fused rows of a run's errors.parquet."""
    t = pq.read_table(run["evaluate"][1] / "errors.parquet")
    fused = np.asarray(t.column("source").to_pylist()) == "fused"
    xyz = np.stack([t.column(c).to_numpy() for c in ("x_m", "y_m", "z_m")], axis=1)
    return t.column("frame_id").to_numpy()[fused], t.column("error_m").to_numpy()[fused], xyz[fused]


def accurate_voxels(error_m: np.ndarray, xyz: np.ndarray) -> int:
    return len(np.unique(np.floor(xyz[error_m <= 0.1] / 0.1).astype(np.int64), axis=0))


def test_submap_frames_land_on_the_true_surface(runs: Runs) -> None:
    fid, err, xyz = fused_errors(runs.stride1)
    own_fid, own_err, own_xyz = fused_errors(runs.default)
    on_frames, on_keyframes = err[fid >= 0], err[fid == -1]
    assert (own_fid == -1).all() and on_frames.size >= 100
    # The keyframes' own points are the same with and without submaps.
    np.testing.assert_array_equal(np.sort(on_keyframes), np.sort(own_err))
    assert np.median(on_frames) <= 1.5 * np.median(on_keyframes)
    with_submaps, without = accurate_voxels(err, xyz), accurate_voxels(own_err, own_xyz)
    assert with_submaps > 1.5 * without
    print(
        f"\nsubmaps stride 1: {on_frames.size} frame fused points, median error"
        f" {np.median(on_frames):.4f} m vs keyframes' {on_keyframes.size} at"
        f" {np.median(on_keyframes):.4f} m; voxels within 0.1 m: {with_submaps} vs {without}"
    )
