"""Scan matching on synthetic piling fields: consensus search, ICP, covariance."""

from __future__ import annotations

import numpy as np

from sonarmap.stages.slam.pose_graph import se2_between, se2_compose, se2_inverse
from sonarmap.stages.slam.scan_matching import (
    OccupancyScorer,
    icp_2d,
    match_scans,
    transform_points,
    voxel_downsample,
)

CENTERS = np.random.default_rng(1).uniform(-15, 15, (25, 2))


def _scan(pose: np.ndarray, seed: int) -> np.ndarray:
    """Leading-edge arcs (radius 0.3 m) of the pilings within 20 m, in the frame of `pose`."""
    rng = np.random.default_rng(seed)
    parts = []
    for c in CENTERS:
        v = c - pose[:2]
        if not 1.0 < np.linalg.norm(v) < 20.0:
            continue
        a = np.arctan2(-v[1], -v[0]) + rng.uniform(-1.2, 1.2, 30)
        parts.append(
            c + 0.3 * np.column_stack([np.cos(a), np.sin(a)]) + rng.normal(0, 0.03, (30, 2))
        )
    return transform_points(se2_inverse(pose), np.concatenate(parts))


def _error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = se2_between(a, b)
    return float(np.hypot(d[0], d[1])), float(abs(d[2]))


def test_match_recovers_motion_from_a_wrong_odometry_guess() -> None:
    target_pose, source_pose = np.zeros(3), np.array([1.8, 0.5, 0.12])
    target = voxel_downsample(_scan(target_pose, 0), 0.2)
    source = voxel_downsample(_scan(source_pose, 1), 0.2)
    truth = se2_between(target_pose, source_pose)
    guess = se2_compose(truth, np.array([0.9, -0.8, 0.25]))
    result = match_scans(source, target, guess, np.array([1.0, 1.0, 0.3]))
    t_err, r_err = _error(truth, result.pose)
    assert t_err < 0.05 and r_err < np.deg2rad(0.5)
    assert _error(truth, result.initial)[0] < 0.5  # within the point noise (dilation radius)
    assert result.overlap > 0.8 * len(source)
    assert np.all(np.linalg.eigvalsh(result.covariance) > 0)
    plain = icp_2d(source, target, guess)
    assert _error(truth, plain)[0] > 0.5  # ICP alone from the guess lands in a wrong basin


def test_consensus_score_matches_a_reference_loop() -> None:
    rng = np.random.default_rng(2)
    target = rng.uniform(-5, 5, (60, 2))
    source = rng.uniform(-5, 5, (40, 2))
    scorer = OccupancyScorer(target, 0.1, 0.5)
    poses = rng.uniform([-1, -1, -0.3], [1, 1, 0.3], (7, 3))
    got = scorer.score(poses, source)
    for pose, count in zip(poses, got, strict=True):
        moved = transform_points(pose, source)
        ref = 0
        for p in moved:
            cell = np.floor((p - scorer.origin) / 0.1).astype(int)
            inside = np.all(cell >= 0) and np.all(cell < scorer.grid.shape)
            ref += int(inside and scorer.grid[cell[0], cell[1]])
        assert ref == count
    # a cell is occupied iff its corner lies within the radius of a target point (up to one cell)
    occupied = np.argwhere(scorer.grid)[:50] * 0.1 + scorer.origin
    d = np.min(np.linalg.norm(occupied[:, None] - target[None], axis=2), axis=1)
    assert np.all(d <= 0.5 + 0.15)
