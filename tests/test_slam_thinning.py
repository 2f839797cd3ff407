"""SLAM's scan-matching inputs thinned and outlier-filtered before ICP (issue 50, item 5)."""

from __future__ import annotations

import numpy as np

from sonarmap.stages.slam.config import SlamConfig
from sonarmap.stages.slam.health import slam_summary
from sonarmap.stages.slam.scan_matching import voxel_downsample
from sonarmap.stages.slam.thinning import (
    cell_inliers,
    radius_inliers,
    thin_and_filter,
    voxel_thin,
)


def test_radius_filter_drops_isolated_points_and_keeps_dense_structure() -> None:
    wall = np.column_stack([np.arange(0.0, 10.0, 0.25), np.full(40, 5.0)])  # 10 m wall
    lonely = np.array([[20.0, 20.0], [-15.0, 3.0], [0.0, -12.0]])
    pair = np.array([[30.0, 0.0], [30.3, 0.0]])  # two detections, each with one neighbour
    points = np.concatenate([wall, lonely, pair])
    keep = radius_inliers(np.zeros(len(points), np.int64), points, 1.0, 5)
    assert keep[1 : len(wall) - 1].all()  # each end has only 4 others within 1 m
    assert not keep[len(wall) :].any()


def test_lone_false_alarms_are_dropped_at_every_range_a_far_piling_is_kept() -> None:
    """False alarms at the front end's per-cell rate (1e-3) over a 512-beam, 600-bin image,
    and a piling 25 m out (6 beams, runs of 4 bins): counted in cells, the false alarms go
    at every range and the piling stays. The metric radius filter keeps the near-range
    false alarms (cells there are dense in metres) and drops the piling."""
    rng = np.random.default_rng(3)
    cells = np.flatnonzero(rng.random(512 * 600) < 1e-3)
    noise_b, noise_r = cells // 600, cells % 600
    pile_b, pile_r = np.repeat(np.arange(250, 256), 4), np.tile(np.arange(500, 504), 6)
    pile_r = pile_r + np.repeat([0, 0, 1, 1, 0, 0], 4)  # the arc's edge curves back
    beam, bins = np.r_[noise_b, pile_b], np.r_[noise_r, pile_r]
    kf = np.zeros(len(beam), np.int64)
    keep = cell_inliers(kf, beam, bins, (kf, beam, bins), 2, 6, 3)
    is_pile = np.arange(len(beam)) >= len(noise_b)
    assert keep[is_pile].all()
    assert keep[~is_pile].sum() <= 1  # expected: 0.01 of the ~300
    # The same cells in metres (5 cm bins, 130 deg fan), each beam's leading edge, thinned
    # on 0.25 m voxels and radius-filtered (1 m, 5 neighbours) as the stage does without it.
    first = np.r_[True, (beam[1:] != beam[:-1]) | (bins[1:] != bins[:-1] + 1)]
    angle = np.deg2rad(-65.0 + 130.0 * (beam[first] + 0.5) / 512)
    rng_m = 0.05 * (bins[first] + 0.5)
    xy = np.column_stack([rng_m * np.cos(angle), rng_m * np.sin(angle)])
    metric = thin_and_filter(kf[first], xy, 0.25, 1.0, 5).points
    pile = xy[is_pile[first]].mean(axis=0)
    assert (np.hypot(*metric.T) < 5.0).sum() > 10  # near-range false alarms kept
    assert (np.hypot(*(metric - pile).T) > 1.0).all()  # the piling dropped


def test_cell_filter_counts_detections_within_the_keyframe_only() -> None:
    beam, bins = np.array([10, 11, 12, 10]), np.array([100, 100, 101, 102])
    both = cell_inliers(
        np.zeros(4, np.int64), beam, bins, (np.zeros(4, np.int64), beam, bins), 2, 6, 3
    )
    split = np.array([0, 0, 1, 1])
    apart = cell_inliers(split, beam, bins, (split, beam, bins), 2, 6, 3)
    assert both.all() and not apart.any()


def test_radius_filter_counts_neighbours_within_the_keyframe_only() -> None:
    blob = np.random.default_rng(0).normal(0.0, 0.2, (6, 2))  # 6 points: 5 neighbours each
    points = np.concatenate([blob, blob[:3]])
    same = radius_inliers(np.zeros(9, np.int64), points, 1.0, 5)
    apart = radius_inliers(np.r_[np.zeros(6), np.ones(3)].astype(np.int64), points, 1.0, 5)
    assert same.all()
    assert apart[:6].all() and not apart[6:].any()


def test_thinning_bounds_points_per_keyframe_whatever_the_detections() -> None:
    rng = np.random.default_rng(1)
    voxel, side = 0.25, 20.0
    bound = int(np.ceil(side / voxel) + 1) ** 2  # cells a side x side square can touch
    for n in (1_000, 100_000, 400_000):
        pts = rng.uniform(0.0, side, (n, 2))
        kf = rng.integers(0, 2, n)
        out = thin_and_filter(kf, pts, voxel, 1.0, 5)
        per_keyframe = np.bincount(out.keyframe, minlength=2)
        assert per_keyframe.max() <= bound
        assert out.input_points == n and out.thinned_points == out.outliers + len(out.points)
    # a flood fills the grid: the 400k points are thinned to the bound, not beyond it
    assert per_keyframe.min() > 0.9 * (side / voxel) ** 2


def test_voxel_thin_is_voxel_downsample_per_keyframe() -> None:
    rng = np.random.default_rng(2)
    kf = np.sort(rng.integers(3, 9, 5_000))
    pts = rng.normal(0.0, 8.0, (5_000, 2))
    out_kf, out = voxel_thin(kf, pts, 0.25)
    for k in np.unique(kf):
        np.testing.assert_array_equal(out[out_kf == k], voxel_downsample(pts[kf == k], 0.25))


def test_summary_counts_dropped_points_without_warning() -> None:
    """The share dropped is recorded, not warned: at the front end's stated false-alarm
    rate a sparse scene has most of its points isolated by design."""
    config = SlamConfig()
    ids = np.arange(3)
    dr = np.zeros((3, 3))
    dr[:, 0] = [0.0, 1.0, 2.0]
    t_s = np.array([0.0, 4.0, 8.0])
    counts = {"thinned": 1000, "outliers_removed": 12, "kept": 988}
    quiet = slam_summary(config, [], ids, dr, dr, t_s, False, counts)
    assert quiet["points"]["outliers_removed"] == 12 and not quiet["warnings"]
    noisy = {"thinned": 1000, "outliers_removed": 700, "kept": 300}
    sparse = slam_summary(config, [], ids, dr, dr, t_s, False, noisy)
    assert sparse["points"]["outliers_removed"] == 700 and not sparse["warnings"]


def test_budget_keeps_the_densest_points_of_keyframes_over_it_only() -> None:
    rng = np.random.default_rng(3)
    speckle = rng.uniform(0.0, 30.0, (3_000, 2))
    wall = np.column_stack([np.full(200, 15.0), np.linspace(5.0, 25.0, 200)])
    quiet = np.column_stack([np.arange(0.0, 10.0, 0.25), np.zeros(40)])
    kf = np.r_[np.zeros(len(speckle) + len(wall)), np.ones(len(quiet))].astype(np.int64)
    points = np.concatenate([speckle, wall, quiet])
    out = thin_and_filter(kf, points, 0.05, None, 5, max_points=300)
    flooded = out.points[out.keyframe == 0]
    assert len(flooded) == 300
    on_wall = np.abs(flooded[:, 0] - 15.0) < 0.05
    assert on_wall.mean() > 0.5  # the wall's points, most of the 300 kept (6 % of input)
    np.testing.assert_array_equal(out.points[out.keyframe == 1], voxel_downsample(quiet, 0.05))
    assert out.over_budget_keyframes == 1
    assert out.over_budget_points == out.thinned_points - len(out.points)
