"""Multi-view class pooling: which sightings pool, and how their distributions combine."""

from __future__ import annotations

import numpy as np

from sonarmap.stages.classify.view_pooling import along_track_m, pool_views, sighting_world_xy

CYL, RECT = 0, 1


def _dist(p_cyl: float) -> np.ndarray:
    return np.array([p_cyl, 1.0 - p_cyl])


def _pool(prob, xy, kf, track, rng, **kw):
    cfg = {"radius_m": 0.5, "window_m": 40.0, "range_scale_m": 20.0, **kw}
    return pool_views(
        np.asarray(prob, float),
        np.asarray(xy, float),
        np.asarray(kf),
        np.asarray(track, float),
        np.asarray(rng, float),
        **cfg,
    )


def test_close_confident_views_outvote_a_far_confidently_wrong_one() -> None:
    # One piling: right at 6 and 9 m, confidently wrong at 26 m (a square at that range).
    prob = [_dist(0.999), _dist(0.995), _dist(0.004)]
    pooled, n_views = _pool(prob, [[0, 0], [0.1, 0], [0, 0.2]], [1, 2, 3], [0, 2, 4], [6, 9, 26])
    assert n_views.tolist() == [3, 3, 3]
    assert (pooled[:, CYL] > 0.99).all()
    # The arithmetic mean would leave the far sighting at about 0.67: "unknown".
    assert np.mean([p[CYL] for p in prob]) < 0.7


def test_agreeing_views_stay_confident_where_the_mean_would_not() -> None:
    # Log-linear pool with equal weights: 0.999 and 0.95 -> about 0.993, the mean 0.9745.
    pooled, _ = _pool(
        [_dist(0.999), _dist(0.95)], [[0, 0], [0, 0.1]], [1, 2], [0, 2], [5, 5],
        range_scale_m=None,
    )  # fmt: skip
    expected = np.sqrt(0.999 * 0.95) / (np.sqrt(0.999 * 0.95) + np.sqrt(0.001 * 0.05))
    np.testing.assert_allclose(pooled[:, CYL], expected, rtol=1e-12)
    assert pooled[0, CYL] > 0.99


def test_only_other_keyframes_near_in_space_and_along_the_track_pool() -> None:
    prob = [_dist(0.9), _dist(0.2), _dist(0.2), _dist(0.2), _dist(0.2)]
    xy = [[0, 0], [0.3, 0], [0.2, 0.1], [1.0, 0], [0, 0.1]]
    kf = [1, 1, 2, 3, 9]  # same keyframe; near; too far in space; too far along the track
    track = [0, 0, 2, 4, 100]
    pooled, n_views = _pool(prob, xy, kf, track, [5] * 5)
    assert n_views.tolist() == [2, 2, 3, 1, 1]
    np.testing.assert_allclose(pooled[3:], np.asarray(prob)[3:])  # alone: unchanged
    assert pooled[0, CYL] < 0.9  # pooled with sighting 2, not with 1 (its own keyframe)


def test_pooling_is_independent_of_the_input_order() -> None:
    rng = np.random.default_rng(3)
    n = 200
    prob = rng.dirichlet(np.ones(3), n)
    xy = rng.uniform(0, 5, (n, 2))
    kf = rng.integers(0, 20, n)
    track = 2.0 * kf
    r = rng.uniform(1, 30, n)
    pooled, n_views = _pool(prob, xy, kf, track, r)
    assert (n_views > 1).sum() > 50
    np.testing.assert_allclose(pooled.sum(axis=1), 1.0, rtol=1e-12)
    perm = rng.permutation(n)
    again, n_again = _pool(prob[perm], xy[perm], kf[perm], track[perm], r[perm])
    np.testing.assert_array_equal(n_again, n_views[perm])
    np.testing.assert_allclose(again, pooled[perm], rtol=1e-12)


def test_world_positions_follow_the_pose_and_the_mounting() -> None:
    T = np.eye(4)
    T[:3, 3] = [1.0, 0.0, -0.5]  # sonar 1 m ahead of the vehicle's origin
    pose = np.array([[10.0, 5.0, np.pi / 2]])  # facing +y
    world = sighting_world_xy(np.array([[3.0, 0.5]]), pose, T)
    np.testing.assert_allclose(world, [[10.0 - 0.5, 5.0 + 4.0]], atol=1e-12)
    np.testing.assert_allclose(along_track_m(np.array([[0, 0], [3, 4], [3, 5]])), [0, 5, 6])


def test_nothing_to_pool() -> None:
    pooled, n_views = _pool(np.zeros((0, 2)), np.zeros((0, 2)), [], [], [])
    assert pooled.shape == (0, 2) and n_views.shape == (0,)
