"""The slam stage's fast paths give the same bits as the plain computations they replace.

The stage's outputs must stay byte-identical (issue 22), so each reference below is the
code the fast path replaced, compared with `tobytes` / exact equality, not a tolerance.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from scipy import ndimage

from sonarmap.stages.slam.config import SlamConfig
from sonarmap.stages.slam.frontend import _FrontEnd
from sonarmap.stages.slam.points import keyframe_points
from sonarmap.stages.slam.scan_matching import (
    OccupancyScorer,
    _lattice,
    _lattice_axes,
    voxel_downsample,
)


def _voxel_reference(points: np.ndarray, voxel_m: float) -> np.ndarray:
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 2))
    np.add.at(sums, inverse.reshape(-1), points)
    return sums / counts[:, None]


@pytest.mark.parametrize("scale_m", [0.3, 8.0, 400.0])
@pytest.mark.parametrize("voxel_m", [0.05, 0.25, 1.0])
def test_voxel_downsample_equals_the_rowwise_unique_reference(
    scale_m: float, voxel_m: float
) -> None:
    rng = np.random.default_rng(int(scale_m * 10 + voxel_m * 100))
    for n in (1, 2, 50, 3000):
        points = rng.normal(size=(n, 2)) * scale_m - scale_m / 2
        got, want = voxel_downsample(points, voxel_m), _voxel_reference(points, voxel_m)
        assert got.shape == want.shape and got.tobytes() == want.tobytes()
    assert voxel_downsample(np.zeros((0, 2)), voxel_m).shape == (0, 2)
    # spans too wide to fold into one int64 take the row-wise path
    wide = np.array([[1e17, -1e17], [-1e17, 1e17], [0.3, 0.2], [0.31, 0.21]])
    assert voxel_downsample(wide, voxel_m).tobytes() == _voxel_reference(wide, voxel_m).tobytes()


@pytest.mark.parametrize(("resolution_m", "radius_m"), [(0.25, 0.5), (0.1, 0.5), (0.07, 0.33)])
def test_occupancy_grid_equals_the_distance_transform_reference(
    resolution_m: float, radius_m: float
) -> None:
    rng = np.random.default_rng(3)
    target = rng.uniform(-10, 10, (300, 2))
    scorer = OccupancyScorer(target, resolution_m, radius_m)
    cells = np.floor((target - scorer.origin) / resolution_m).astype(int)
    empty = np.ones(scorer.grid.shape, dtype=bool)
    empty[cells[:, 0], cells[:, 1]] = False
    want = ndimage.distance_transform_edt(empty) * resolution_m <= radius_m
    want[[0, -1], :] = False
    want[:, [0, -1]] = False
    assert np.array_equal(scorer.grid, want)


def test_lattice_score_per_axis_pair_equals_scoring_each_pose() -> None:
    rng = np.random.default_rng(4)
    for _ in range(5):
        scorer = OccupancyScorer(rng.uniform(-20, 20, (500, 2)), 0.25, 0.5)
        source = rng.uniform(-25, 25, (150, 2))
        half = np.array([1.0, 1.0, 0.1])
        axes = _lattice_axes(rng.normal(size=3), half, half / 4)
        got, want = scorer.score_lattice(axes, source), scorer.score(_lattice(axes), source)
        assert np.array_equal(got, want)
        assert want.max() > 0  # the comparison covers occupied cells, not only empty ones


def test_keyframe_points_keeps_only_horizontal_rows_and_skips_nulls() -> None:
    features = pa.table(
        {
            "keyframe_id": pa.array([0, 0, 1, 1], pa.int64()),
            "sonar": pa.array(["horizontal", "vertical", None, "horizontal"]),
            "range_bin": pa.array([10, 10, 10, 20], pa.int64()),
            "beam": pa.array([3, 3, 3, 4], pa.int64()),
            "range_m": pa.array([5.0, 6.0, 7.0, 8.0]),
            "angle_rad": pa.array([0.0, 0.0, 0.0, 0.0]),
        }
    )
    points = keyframe_points(np.array([0, 1]), features, np.eye(4), 0.01)
    assert [p.tolist() for p in points] == [[[5.0, 0.0]], [[8.0, 0.0]]]


def test_a_cached_keyframe_cloud_is_rebuilt_when_the_estimate_changes() -> None:
    rng = np.random.default_rng(5)
    front = _FrontEnd(SlamConfig(), [rng.uniform(-5, 5, (40, 2)) for _ in range(3)])
    front.est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.1], [2.0, 0.0, 0.2]])
    first = front._cloud(range(0, 3), 2)
    assert front._cloud(range(0, 3), 2) is first
    front.est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.4], [2.0, 0.0, 0.2]])
    again = front._cloud(range(0, 3), 2)
    assert again is not first and not np.array_equal(again, first)
