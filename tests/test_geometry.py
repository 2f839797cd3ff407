"""stages/kernels/geometry.py: conventions, round trips and scipy agreement, and the one
home rule (no rotation, quaternion, Euler or Eq. 1 formula anywhere else)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sonarmap.stages.kernels import geometry as g

ROOT = Path(__file__).resolve().parent.parent
RNG = np.random.default_rng(36)
N = 500


def _rpy(n: int = N) -> np.ndarray:
    """Random roll, pitch, yaw, pitch kept off gimbal lock (|pitch| < 80 deg)."""
    a = RNG.uniform(-np.pi, np.pi, (n, 3))
    a[:, 1] *= np.deg2rad(80.0) / np.pi
    return a


def _quat(n: int = N) -> np.ndarray:
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# --- conventions -------------------------------------------------------------------


def test_a_positive_yaw_turns_x_towards_y() -> None:
    R = g.matrix_from_rpy([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_roll_turns_y_to_z_and_pitch_turns_z_to_x() -> None:
    np.testing.assert_allclose(
        g.matrix_from_rpy([np.pi / 2, 0, 0]) @ [0, 1, 0], [0, 0, 1], atol=1e-15
    )
    np.testing.assert_allclose(
        g.matrix_from_rpy([0, np.pi / 2, 0]) @ [0, 0, 1], [1, 0, 0], atol=1e-15
    )


def test_angles_compose_as_rz_ry_rx() -> None:
    r, p, y = 0.3, -0.4, 1.1
    Rx, Ry, Rz = (g.matrix_from_rpy(v) for v in ([r, 0, 0], [0, p, 0], [0, 0, y]))
    np.testing.assert_allclose(g.matrix_from_rpy([r, p, y]), Rz @ Ry @ Rx, atol=1e-15)


def test_quaternions_are_scalar_last() -> None:
    q = g.quat_from_rpy([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(q, [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(g.matrix_from_quat([0, 0, 0, 1]), np.eye(3), atol=0)


# --- rotations against scipy (the closed forms must agree to 1e-12) -----------------


def test_matrix_from_rpy_matches_scipy() -> None:
    a = _rpy()
    np.testing.assert_allclose(
        g.matrix_from_rpy(a), Rotation.from_euler("xyz", a).as_matrix(), atol=1e-12
    )


def test_the_simulators_product_form_is_the_same_rotation() -> None:
    a = _rpy(50)
    product = g.matrix_from_rpy_product(a)
    assert product.shape == (50, 3, 3)
    np.testing.assert_allclose(product, g.matrix_from_rpy(a), atol=1e-15)
    np.testing.assert_allclose(product, Rotation.from_euler("xyz", a).as_matrix(), atol=1e-12)
    assert g.matrix_from_rpy_product(a[0]).tobytes() == product[0].tobytes()


def test_rpy_from_matrix_matches_scipy_and_inverts_matrix_from_rpy() -> None:
    a = _rpy()
    R = g.matrix_from_rpy(a)
    np.testing.assert_allclose(g.rpy_from_matrix(R), a, atol=1e-12)
    np.testing.assert_allclose(
        g.rpy_from_matrix(R), Rotation.from_matrix(R).as_euler("xyz"), atol=1e-12
    )


def test_quat_from_rpy_matches_scipy_and_rpy_from_quat_inverts_it() -> None:
    a = _rpy()
    q = g.quat_from_rpy(a)
    np.testing.assert_allclose(q, Rotation.from_euler("xyz", a).as_quat(), atol=1e-12)
    np.testing.assert_allclose(g.rpy_from_quat(q), a, atol=1e-12)
    np.testing.assert_allclose(g.rpy_from_quat(-3.0 * q), a, atol=1e-12)  # sign and scale free


def test_rpy_from_quat_matches_scipy() -> None:
    q = _quat()
    q = q[np.abs(Rotation.from_quat(q).as_euler("xyz")[:, 1]) < np.deg2rad(80)]
    np.testing.assert_allclose(
        g.rpy_from_quat(q), Rotation.from_quat(q).as_euler("xyz"), atol=1e-12
    )


def test_quat_from_matrix_matches_scipy_with_w_non_negative() -> None:
    q = _quat()
    # Half-turns exercise every branch of Shepperd's method (trace <= 0, each diagonal).
    half_turns = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 1, 0, 1e-3]], float)
    q = np.vstack([q, half_turns / np.linalg.norm(half_turns, axis=1, keepdims=True)])
    R = Rotation.from_quat(q).as_matrix()
    mine = g.quat_from_matrix(R)
    assert np.all(mine[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(mine, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(mine, Rotation.from_matrix(R).as_quat(canonical=True), atol=1e-12)
    np.testing.assert_allclose(g.matrix_from_quat(mine), R, atol=1e-12)


def test_quat_from_matrix_of_one_matrix_equals_that_row_of_many() -> None:
    R = Rotation.from_quat(_quat(50)).as_matrix()
    many = g.quat_from_matrix(R)
    one = np.array([g.quat_from_matrix(m) for m in R])
    assert one.shape == (50, 4)
    assert one.tobytes() == many.tobytes()


def test_matrix_from_quat_matches_scipy_and_normalises() -> None:
    q = _quat()
    np.testing.assert_allclose(
        g.matrix_from_quat(2.5 * q), Rotation.from_quat(q).as_matrix(), atol=1e-12
    )


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [np.nan, 0, 0, 1], [np.inf, 0, 0, 1]])
def test_matrix_from_quat_refuses_a_quaternion_without_a_rotation(bad: list[float]) -> None:
    with pytest.raises(ValueError, match="zero or non-finite"):
        g.matrix_from_quat(bad)


# --- SE(3) and SE(2) ---------------------------------------------------------------


def _poses(n: int = N) -> np.ndarray:
    return np.column_stack([RNG.uniform(-50, 50, (n, 3)), _rpy(n)])


def test_se3_pose_round_trip_and_layout() -> None:
    p = _poses()
    T = g.se3_from_pose(p)
    assert T.shape == (N, 4, 4)
    np.testing.assert_array_equal(T[:, 3], np.tile([0, 0, 0, 1.0], (N, 1)))
    np.testing.assert_allclose(g.pose_from_se3(T), p, atol=1e-12)


def test_se3_inverse_and_compose() -> None:
    A, B, C = (g.se3_from_pose(_poses(20)) for _ in range(3))
    np.testing.assert_allclose(
        g.se3_compose(A, g.se3_inverse(A)), np.tile(np.eye(4), (20, 1, 1)), atol=1e-12
    )
    np.testing.assert_allclose(g.se3_inverse(A), np.linalg.inv(A), atol=1e-12)
    np.testing.assert_allclose(
        g.se3_compose(g.se3_compose(A, B), C), g.se3_compose(A, g.se3_compose(B, C)), atol=1e-9
    )


def test_se3_apply_maps_points_from_b_into_a() -> None:
    T = g.se3_from_pose(_poses(1))[0]
    pts = RNG.normal(size=(30, 3))
    np.testing.assert_allclose(g.se3_apply(T, pts), pts @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    back = g.se3_apply(g.se3_inverse(T), g.se3_apply(T, pts))
    np.testing.assert_allclose(back, pts, atol=1e-12)


def test_se2_is_the_planar_part_of_se3() -> None:
    x, y, yaw = 3.0, -2.0, 0.7
    T2 = g.se2(x, y, yaw)
    T3 = g.se3_from_pose([x, y, 0.0, 0.0, 0.0, yaw])
    np.testing.assert_allclose(T2[:2, :2], T3[:2, :2], atol=1e-15)
    pts = RNG.normal(size=(10, 2))
    expect = g.se3_apply(T3, np.column_stack([pts, np.zeros(10)]))[:, :2]
    np.testing.assert_allclose(g.se2_apply(T2, pts), expect, atol=1e-12)
    assert g.se2(np.zeros(4), np.zeros(4), np.zeros(4)).shape == (4, 3, 3)


# --- Eq. 1 -------------------------------------------------------------------------


def test_eq1_both_ways() -> None:
    rng_m = RNG.uniform(0.1, 30, N)
    bearing = RNG.uniform(-1.1, 1.1, N)
    elevation = RNG.uniform(-0.17, 0.17, N)
    xyz = g.polar_to_xyz(rng_m, bearing, elevation)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), rng_m, rtol=1e-14)
    np.testing.assert_allclose(
        g.xyz_to_polar(xyz), np.column_stack([rng_m, bearing, elevation]), atol=1e-12
    )
    np.testing.assert_array_equal(g.xyz_to_polar(np.zeros((1, 3))), np.zeros((1, 3)))


def test_eq1_axes_bearing_left_elevation_up() -> None:
    np.testing.assert_allclose(g.polar_to_xyz(2.0, np.pi / 2, 0.0), [0, 2, 0], atol=1e-15)
    np.testing.assert_allclose(g.polar_to_xyz(2.0, 0.0, np.pi / 2), [0, 0, 2], atol=1e-15)


def test_fan_plane_is_eq1_at_zero_elevation() -> None:
    rng_m, bearing = RNG.uniform(0.1, 30, N), RNG.uniform(-1.1, 1.1, N)
    xy = g.fan_to_xy(rng_m, bearing)
    assert xy.tobytes() == g.polar_to_xyz(rng_m, bearing, 0.0)[:, :2].copy().tobytes()
    np.testing.assert_allclose(
        g.fan_to_xy([2.0, 3.0], [0.0, np.pi / 2]), [[2, 0], [0, 3]], atol=1e-12
    )


def test_fan_in_frame_applies_the_mounting() -> None:
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, 0.1]
    pts = g.fan_in_frame(np.array([10.0, 4.0]), np.array([0.0, np.pi / 2]), T)
    np.testing.assert_allclose(pts, [[10.5, 0.0, 0.1], [0.5, 4.0, 0.1]], atol=1e-12)
    tilted = g.se3(g.matrix_from_rpy([np.pi / 2, 0, 0]), [0, 0, 0])  # fan plane turned upright
    np.testing.assert_allclose(g.fan_in_frame([1.0], [np.pi / 2], tilted), [[0, 0, 1]], atol=1e-15)


# --- one home ----------------------------------------------------------------------

REMOVED = (
    "_quaternion_rpy",
    "quaternion_from_matrix",
    "_quat_matrix",
    "quat_to_rpy",
    "rpy_from_rotation",
    "spherical_points",
    "fan_xy",
    "polar_to_base",
    "rot_rpy",
    "rot_x",
    "rot_z",
    "rotation_rpy",
    "pose_to_matrix",
    "apply_se2",
)
"""The copies geometry.py replaced: six rotation helpers, three Eq. 1 copies, and others."""

HAND_ROLLED = {
    "half-angle quaternion": r"np\.(?:cos|sin)\(\w+ / 2\)|/ 2 for \w+ in rpy",
    "quaternion to matrix/Euler": r"1 - 2 \* \(\w \* \w \+ \w \* \w\)|2 \* \(\w \* \w [+-] \w \* \w\)",
    "Euler from a matrix": r"arctan2\(R\[[^\]]*2, 1\]|arcsin\(np\.clip\(-R\[",
    "R = Rz Ry Rx closed form": r"\b[cs]y \* [cs]p \* [cs]r\b",
    "Shepperd's method": r"np\.trace\(m\)|np\.sqrt\(tr \+ 1",
    "Eq. 1 spherical": r"\* np\.cos\(elev\w*\)|\br\w* \* c\w* \* np\.(?:cos|sin)\(",
    "Eq. 1 fan plane": r"\br(?:ange_m)? \* np\.(?:cos|sin)\((?:th|theta|d|bearing\w*|angle\w*)\)",
}


def _sources() -> list[Path]:
    home = ROOT / "stages" / "kernels" / "geometry.py"
    return [
        p
        for d in ("pipeline", "stages", "sim")
        for p in sorted((ROOT / d).rglob("*.py"))
        if p != home
    ]


def _offences(paths: list[Path]) -> list[str]:
    names = re.compile(r"\b(?:" + "|".join(map(re.escape, REMOVED)) + r")\b")
    formulas = {k: re.compile(v) for k, v in HAND_ROLLED.items()}
    bad = []
    for path in paths:
        for no, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            where = f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name}:{no}"
            if m := names.search(code):
                bad.append(f"{where}: {m.group(0)}")
            bad.extend(f"{where}: {k}" for k, rx in formulas.items() if rx.search(code))
    return bad


def test_geometry_has_one_home() -> None:
    assert not (ROOT / "sim" / "geometry.py").exists()
    assert _offences(_sources()) == []


def test_the_one_home_check_catches_copies(tmp_path: Path) -> None:
    sample = tmp_path / "copy.py"
    sample.write_text(
        "def quat_to_rpy(q):\n"
        "    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))\n"
        "    cr, sr = np.cos(roll / 2), np.sin(roll / 2)\n"
        "    m = cy * sp * sr - sy * cr\n"
        "    yaw = np.arctan2(R[:, 2, 1], R[:, 2, 2])\n"
        "    x = range_m * c * np.cos(bearing_rad)\n"
        "    y = r * np.sin(th)\n"
    )
    found = {line.split(": ", 1)[1] for line in _offences([sample])}
    assert found == {"quat_to_rpy", *HAND_ROLLED} - {"Shepperd's method"}


# --- the reader's use of it: /tf_static mountings ----------------------------------


def _with_tf_static(tmp_path: Path, quat: list[float], xyz: list[float]) -> Path:
    """A small synthetic recording plus a /tf_static giving the horizontal sonar's mount."""
    from mcap.reader import make_reader

    from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
    from sonarmap.schemas.topics import FRAME_BASE, TOPIC_TF_STATIC
    from tests.fixtures import write_recording

    plain, out = tmp_path / "plain.mcap", tmp_path / "rec.mcap"
    write_recording(plain, n_pings=4)
    t = ros2_typestore().types
    tf = t["geometry_msgs/msg/TransformStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=FRAME_BASE
        ),
        child_frame_id="sonar",  # the frame_id of the synthetic recording's sonar images
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=t["geometry_msgs/msg/Quaternion"](x=quat[0], y=quat[1], z=quat[2], w=quat[3]),
        ),
    )
    with plain.open("rb") as f, out.open("wb") as g, Ros2McapWriter(g) as w:
        first = True
        for schema, channel, m in make_reader(f).iter_messages():
            if first:
                w.write(
                    TOPIC_TF_STATIC,
                    "tf2_msgs/msg/TFMessage",
                    t["tf2_msgs/msg/TFMessage"](transforms=[tf]),
                    m.log_time,
                )
                first = False
            assert schema is not None
            w.write_raw(channel.topic, schema.name, m.data, m.log_time)
    return out


def _mountings(path: Path) -> dict[str, np.ndarray]:
    from sonarmap.pipeline.readers import ReaderOptions, SourceRecording, open_source

    return SourceRecording(open_source(path), ReaderOptions.from_config(None)).mountings()


def test_a_tf_static_mounting_is_read_through_the_geometry_module(tmp_path: Path) -> None:
    q = Rotation.from_euler("xyz", [0.1, -0.2, 0.3]).as_quat()
    mounts = _mountings(_with_tf_static(tmp_path, list(2.0 * q), [0.5, 0.0, 0.1]))
    np.testing.assert_allclose(
        mounts["horizontal"][:3, :3], Rotation.from_quat(q).as_matrix(), atol=1e-12
    )
    np.testing.assert_array_equal(mounts["horizontal"][:3, 3], [0.5, 0.0, 0.1])


@pytest.mark.parametrize(
    ("quat", "xyz", "reason"),
    [
        ([0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.1], "zero or non-finite norm"),
        ([np.nan, 0.0, 0.0, 1.0], [0.5, 0.0, 0.1], "zero or non-finite norm"),
        ([0.0, 0.0, 0.0, 1.0], [0.5, np.inf, 0.1], "translation is not finite"),
    ],
)
def test_a_tf_static_mounting_without_a_pose_is_refused(
    tmp_path: Path, quat: list[float], xyz: list[float], reason: str
) -> None:
    from sonarmap.pipeline.engine.errors import SourceError

    path = _with_tf_static(tmp_path, quat, xyz)
    with pytest.raises(SourceError, match=rf"rec\.mcap: /tf_static: .*-> sonar: .*{reason}"):
        _mountings(path)
