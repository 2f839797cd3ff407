"""Object frames (origin at min range / median bearing, metric) and ICP registration."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.stages.kernels.geometry import se2_apply as apply_se2
from sonarmap.stages.kernels.object_frame import (
    ClassFrame,
    IcpParams,
    ObjectOrigin,
    object_origin,
    register_2d,
    to_object_frame,
    voxel_downsample_2d,
)


def _l_shape(n: int = 120, seed: int = 0) -> np.ndarray:
    """(n, 2) points on an asymmetric L (1.0 m and 0.4 m legs) with 1 cm noise."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1.4, n)
    pts = np.where(t[:, None] < 1.0, np.c_[np.zeros(n), t], np.c_[t - 1.0, np.zeros(n)])
    return pts + rng.normal(0, 0.01, (n, 2))


def _se2(x: float, y: float, yaw_deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(yaw_deg)), np.sin(np.deg2rad(yaw_deg))
    return np.array([[c, -s, x], [s, c, y], [0, 0, 1.0]])


def test_origin_is_min_range_and_median_bearing() -> None:
    o = object_origin(np.array([5.0, 4.0, 6.0]), np.array([0.1, 0.3, 0.2]))
    assert o == ObjectOrigin(4.0, 0.2)
    with pytest.raises(ValueError):
        object_origin(np.array([]), np.array([]))


def test_object_frame_is_metric_left_positive_and_rotation_invariant() -> None:
    r = np.array([4.0, 4.0, 5.0])
    b = np.array([0.0, 0.05, 0.0])
    uv = to_object_frame(r, b, ObjectOrigin(4.0, 0.0))
    np.testing.assert_allclose(uv[0], [0.0, 0.0], atol=1e-12)
    assert uv[1, 1] > 0  # larger bearing (left) -> positive cross-range
    np.testing.assert_allclose(uv[2], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.hypot(*(uv[1] - uv[0])), 2 * 4.0 * np.sin(0.025), rtol=1e-12)
    # Turning the sonar (all bearings shift) leaves the object frame unchanged.
    shifted = to_object_frame(r, b - 0.7, object_origin(r, b - 0.7))
    np.testing.assert_allclose(shifted, to_object_frame(r, b, object_origin(r, b)), atol=1e-12)


def test_voxel_downsample_bounds_the_cloud() -> None:
    pts = np.vstack([_l_shape(seed=s) for s in range(20)])
    down = voxel_downsample_2d(pts, 0.05)
    assert down.shape[0] < pts.shape[0] / 10
    assert np.unique(np.floor(down / 0.05), axis=0).shape[0] == down.shape[0]


def test_icp_recovers_a_small_rigid_motion() -> None:
    ref = _l_shape(seed=1)
    T_true = _se2(0.12, -0.08, 7.0)
    moved = apply_se2(np.linalg.inv(T_true), _l_shape(seed=2))
    reg = register_2d(moved, ref, IcpParams())
    assert reg.ok
    np.testing.assert_allclose(reg.T_ref_obj[:2, 2], T_true[:2, 2], atol=0.02)
    yaw = np.rad2deg(np.arctan2(reg.T_ref_obj[1, 0], reg.T_ref_obj[0, 0]))
    assert yaw == pytest.approx(7.0, abs=1.0)


def test_icp_failure_is_reported() -> None:
    ref = _l_shape(seed=1)
    far = _l_shape(seed=2) + np.array([3.0, 3.0])  # nothing within the correspondence distance
    assert not register_2d(far, ref, IcpParams()).ok
    assert not register_2d(ref[:2], ref, IcpParams()).ok  # too few points
    rng = np.random.default_rng(0)
    blob = rng.uniform(-2, 2, (200, 2))  # poor fit: low fitness
    assert not register_2d(blob, ref, IcpParams(max_correspondence_m=0.05)).ok


def test_class_frame_updates_grow_reference_queries_do_not() -> None:
    frame = ClassFrame(IcpParams())
    assert not frame.register(_l_shape()).ok  # no reference yet
    first = frame.add_sighting(_l_shape(seed=0), ObjectOrigin(5.0, 0.1))
    assert first.ok and frame.origin == ObjectOrigin(5.0, 0.1)
    assert frame.reference is not None
    before = frame.reference.copy()
    frame.register(apply_se2(_se2(0.05, 0.0, 3.0), _l_shape(seed=5)))
    np.testing.assert_array_equal(frame.reference, before)
    origin = ObjectOrigin(5.0, 0.0)
    for s in range(30):
        assert frame.add_sighting(apply_se2(_se2(0.03, 0.02, 2.0), _l_shape(seed=s)), origin).ok
    assert frame.reference.shape[0] <= 2 * before.shape[0]  # bounded by the voxel grid
    # A failed registration leaves the reference unchanged.
    ref = frame.reference.copy()
    assert not frame.add_sighting(_l_shape() + 10.0, origin).ok
    np.testing.assert_array_equal(frame.reference, ref)


def _merged(seed: int = 0) -> np.ndarray:
    """A piling merged in 2D with the catwalk it carries: the L, then a 10 m tail 2 m
    behind it, which moves the sighting's origin (median bearing) metres from the piling."""
    rng = np.random.default_rng(seed)
    tail = np.c_[rng.uniform(1.95, 2.05, 400), rng.uniform(1.0, 11.0, 400)]
    return np.vstack([_l_shape(seed=seed), tail]) - np.array([0.0, 5.0])


def test_a_provisional_reference_gives_way_a_confirmed_one_does_not() -> None:
    frame = ClassFrame(IcpParams())
    origin = ObjectOrigin(5.0, 0.0)
    assert frame.add_sighting(_merged(), origin).ok and not frame.confirmed
    # The next sighting, a plain piling, cannot register to the odd first one (the
    # paper's rule would skip it and every later one): it becomes the reference.
    assert not frame.register(_l_shape(seed=1)).ok
    second = frame.add_sighting(_l_shape(seed=1), ObjectOrigin(6.0, 0.2))
    assert second.ok and second.reseeded and not frame.confirmed
    assert frame.origin == ObjectOrigin(6.0, 0.2)
    np.testing.assert_array_equal(frame.reference, voxel_downsample_2d(_l_shape(seed=1), 0.05))
    third = frame.add_sighting(apply_se2(_se2(0.04, -0.02, 3.0), _l_shape(seed=2)), origin)
    assert third.ok and not third.reseeded and frame.confirmed
    # Once confirmed, a sighting that does not register is skipped, as in the paper.
    ref = frame.reference.copy()
    late = frame.add_sighting(_merged(seed=3), origin)
    assert not late.ok and not late.reseeded
    np.testing.assert_array_equal(frame.reference, ref)


def test_a_class_model_starts_again_with_its_new_reference() -> None:
    from sonarmap.stages.infer.config import InferConfig
    from sonarmap.stages.kernels.class_models import new_class_states
    from sonarmap.stages.kernels.class_query import update_object_class
    from sonarmap.stages.kernels.sightings import Sighting

    def sighting(object_id: int, uv: np.ndarray, z_m: float) -> Sighting:
        n = len(uv)
        every = np.arange(n)
        return Sighting(
            object_id, "cylindrical_piling", ObjectOrigin(5.0, 0.0), uv, np.full(n, 5.0),
            np.zeros(n), every, np.ones(n, bool), uv, np.full(n, z_m), every,
        )  # fmt: skip

    state = new_class_states(InferConfig())["cylindrical_piling"]
    assert update_object_class(state, [sighting(0, _merged(), 3.0)], "offset")
    first_cells = state.model.n_cells
    # The plain piling replaces the odd reference, and the heights learned in the old
    # frame (3 m, on the catwalk's cells) go with it: the model holds the new ones only.
    assert set(update_object_class(state, [sighting(1, _l_shape(seed=1), -1.0)], "offset")) == {1}
    assert 0 < state.model.n_cells < first_cells
    q = state.model.query(_l_shape(seed=1), 0.0)
    assert np.nanmax(np.abs(np.r_[q.z_low_m, q.z_high_m] + 1.0)) < 0.3
