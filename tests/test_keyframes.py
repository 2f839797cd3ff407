"""Keyframes stage: pairing, pose interpolation, selection, and the stage on a recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_readers_mcap import T0, trajectory, write_synthetic

from sonarmap.pipeline.readers import open_recording
from sonarmap.schemas.keyframes import KEYFRAMES_SCHEMA
from sonarmap.schemas.recording import PoseTrack
from sonarmap.stages.base import DATASET, StageInputError
from sonarmap.stages.keyframes import STAGE, KeyframesConfig
from sonarmap.stages.keyframes.stage import interpolate_poses, pair_pings, select_keyframes


def test_pairing_nearest_within_tolerance_each_vertical_used_once() -> None:
    h = np.array([0, 100, 200, 300, 400], np.int64)
    v = np.array([5, 95, 104, 260, 1000], np.int64)
    p = pair_pings(h, v, tolerance_ns=10)
    np.testing.assert_array_equal(p.horizontal, [0, 1])
    np.testing.assert_array_equal(
        p.vertical, [0, 2]
    )  # 104 is nearer to 100 than 95? no: |95-100|=5 < |104-100|=4
    assert p.unpaired_horizontal == 3 and p.unpaired_vertical == 3


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.integers(0, 10_000), min_size=1, max_size=40, unique=True),
    st.lists(st.integers(0, 10_000), min_size=1, max_size=40, unique=True),
    st.integers(0, 500),
)
def test_pairing_matches_brute_force(h: list[int], v: list[int], tol: int) -> None:
    h_t, v_t = np.sort(np.array(h, np.int64)), np.sort(np.array(v, np.int64))
    p = pair_pings(h_t, v_t, tol)
    # Reference: nearest (ties to the earlier), closest horizontal wins a shared vertical.
    best: dict[int, tuple[int, int]] = {}
    for i, t in enumerate(h_t):
        d = np.abs(v_t - t)
        j = int(np.argmin(d))
        if d[j] <= tol and (j not in best or d[j] < best[j][1]):
            best[j] = (i, int(d[j]))
    ref = sorted((i, j) for j, (i, _) in best.items())
    assert list(zip(p.horizontal.tolist(), p.vertical.tolist(), strict=True)) == ref
    assert p.unpaired_horizontal == len(h_t) - len(ref)


def test_interpolation_se2_shortest_arc_and_no_extrapolation() -> None:
    track = PoseTrack(
        np.array([0, 10, 20], np.int64),
        np.array([[0.0, 0, -1], [1, 2, -2], [2, 2, -2]]),
        np.array([[0, 0, np.pi - 0.1], [0, 0, -np.pi + 0.1], [0, 0, -np.pi + 0.3]]),
    )
    pose, valid = interpolate_poses(track, np.array([-1, 0, 5, 15, 20, 21], np.int64))
    np.testing.assert_array_equal(valid, [False, True, True, True, True, False])
    assert np.all(np.isnan(pose[~valid]))
    np.testing.assert_allclose(pose[2, :3], [0.5, 1.0, -1.5])
    assert abs(abs(pose[2, 5]) - np.pi) < 1e-9  # through +-pi, not through 0


def test_selection_by_spacing_rotation_and_min_gap() -> None:
    t = np.arange(0, 100, dtype=np.int64) * 500_000_000  # 2 Hz
    x = np.minimum(t * 1e-9, 20.0) * 0.5  # 0.5 m/s for 20 s, then turn in place
    yaw = np.where(t * 1e-9 > 20, 0.2 * (t * 1e-9 - 20), 0.0)
    poses = np.column_stack([x, 0 * x, 0 * x, 0 * x, 0 * x, yaw])
    idx, reasons = select_keyframes(t, poses, 2.0, np.deg2rad(30), 1_000_000_000)
    assert reasons[0] == "first" and idx[0] == 0
    trans = [i for i, r in zip(idx, reasons, strict=True) if r == "translation"]
    np.testing.assert_array_equal(trans, [8, 16, 24, 32, 40])  # every 2 m at 0.5 m/s, 2 Hz
    rot = [i for i, r in zip(idx, reasons, strict=True) if r == "rotation"]
    # 30 deg at 0.2 rad/s = 2.62 s -> every 6th sample (3 s) after the last translation keyframe.
    assert rot and np.all(np.diff(rot) == 6) and rot[0] == 46
    # A min gap longer than the spacing interval thins the keyframes.
    idx2, _ = select_keyframes(t, poses, 2.0, np.deg2rad(30), 10_000_000_000)
    assert np.all(np.diff(t[idx2]) >= 10_000_000_000)


def test_stage_on_synthetic_recording(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    info = write_synthetic(path, n_pings=80, rate_hz=2.0)
    cfg = KeyframesConfig()
    out = STAGE.run(cfg, {"dataset": open_recording(path, cfg)})
    table = out["keyframes"]
    assert table.schema.equals(KEYFRAMES_SCHEMA)
    rows = table.to_pylist()
    # Truth: 0.5 m/s along x for 20 s, then yaw rate 0.1 rad/s in place.
    t_s = (np.array([r["t_ns"] for r in rows]) - T0) * 1e-9
    truth = trajectory(t_s)
    np.testing.assert_allclose([r["x_m"] for r in rows], truth[:, 0] + 0.1, atol=1e-9)
    np.testing.assert_allclose([r["gt_x_m"] for r in rows], truth[:, 0], atol=1e-9)
    np.testing.assert_allclose([r["gt_yaw_rad"] for r in rows], truth[:, 3], atol=1e-9)
    reasons = [r["reason"] for r in rows]
    assert reasons[:5] == ["first"] + ["translation"] * 4  # 8 m of straight travel, 2 m apart
    step = np.diff(truth[:5, 0])  # the first ping at or beyond 2 m (0.25 m per ping)
    assert np.all((step > 2.0 - 1e-6) & (step <= 2.25 + 1e-6))
    assert "rotation" in reasons
    assert all(r["t_vertical_ns"] - r["t_ns"] == 3_000_000 for r in rows)
    frames = list(out["frames"])
    assert [f.keyframe_id for f in frames] == list(range(len(rows)))
    assert [int(f.horizontal.image[0, 0]) for f in frames] == [
        r["ping_index_horizontal"] for r in rows
    ]
    assert [int(f.vertical.image[0, 0]) for f in frames] == [
        100 + r["ping_index_vertical"] for r in rows
    ]
    assert all(f.horizontal.labels is not None for f in frames)
    s = out["sensors"]
    assert s["has_ground_truth"] and s["has_labels"]
    assert s["pairing"]["pairs"] == 80 and s["pairing"]["keyframes"] == len(rows)
    np.testing.assert_allclose(np.array(s["vertical"]["T_base_sonar"])[:3, 3], [0.5, 0.0, 0.1])
    assert out["scene_mesh"].startswith(b"ply")
    assert len(info["ping_t"]) == 80


def test_stage_spacing_4m_halves_translation_keyframes(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    write_synthetic(path, n_pings=38, rate_hz=2.0, labels=False)  # 18.5 s, 9.25 m
    counts = {}
    for spacing in (2.0, 4.0):
        cfg = KeyframesConfig(spacing_m=spacing, rotation_deg=180.0)
        rows = STAGE.run(cfg, {"dataset": open_recording(path, cfg)})["keyframes"].to_pylist()
        counts[spacing] = sum(r["reason"] == "translation" for r in rows)
    assert counts == {2.0: 4, 4.0: 2}


def test_no_keyframe_when_navigation_misses_the_pings(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    write_synthetic(path, n_pings=4, labels=False)
    cfg = KeyframesConfig(pair_tolerance_s=0.001)
    # Bad data, not a bug: the engine reports a StageInputError as exit 2 naming the file.
    with pytest.raises(StageInputError, match="no keyframe: 0 sonar pairs") as refused:
        STAGE.run(cfg, {"dataset": open_recording(path, cfg)})
    assert refused.value.input == DATASET


class _MemoUnits:
    """An in-memory `Units` memo of one dataset that counts what it served."""

    def __init__(self, dataset: str) -> None:
        self.dataset, self.data, self.hits = dataset, {}, 0

    def get(self, key: str) -> dict | None:
        got = self.data.get(key)
        self.hits += got is not None
        return got

    def put(self, key: str, arrays: dict) -> None:
        self.data[key] = {k: np.array(v) for k, v in arrays.items()}


def _images(frames) -> list[tuple[int, int, bytes, bytes]]:
    return [
        (f.keyframe_id, f.t_ns, f.horizontal.image.tobytes(), f.vertical.image.tobytes())
        for f in frames
    ]


def test_recording_unit_serves_every_spacing_and_the_calibration_sample_ignores_it(
    tmp_path: Path,
) -> None:
    """What the stage reads of the whole recording is one unit per dataset: a second
    spacing takes it (the same keyframes, sensors and truth as read from the file), and
    the ping pairs the front end calibrates on are the same at every spacing."""
    path = tmp_path / "d.mcap"
    write_synthetic(path, n_pings=80, rate_hz=2.0)
    memo = _MemoUnits("0" * 64)
    samples = []
    for spacing in (2.0, 4.0):
        cfg = KeyframesConfig(spacing_m=spacing, calibration_pairs=8)
        cached = STAGE.run(cfg, {"dataset": open_recording(path, cfg), "units": memo})
        read = STAGE.run(cfg, {"dataset": open_recording(path, cfg)})
        assert cached["keyframes"].equals(read["keyframes"])
        assert cached["sensors"] == read["sensors"]
        assert _images(cached["frames"]) == _images(read["frames"])
        samples.append(_images(cached["calibration_frames"]))
        assert samples[-1] == _images(read["calibration_frames"])
    assert (len(memo.data), memo.hits) == (1, 1)
    assert samples[0] == samples[1] and len(samples[0]) == 8
    # Each carries its horizontal ping index as its id, on a grid of absolute time.
    assert [s[0] for s in samples[0]] == sorted({s[0] for s in samples[0]})
    other = _MemoUnits("1" * 64)  # another dataset never takes this one's unit
    cfg = KeyframesConfig()
    STAGE.run(cfg, {"dataset": open_recording(path, cfg), "units": other})
    assert other.hits == 0
