"""Geometry: the sonar equation (paper Eq. 1), SE(3), SE(2), rotations and quaternions.

The one home for geometry in sonarmap: stages, readers, formats and the simulator call
these functions and write no rotation, quaternion, Euler-angle or Eq. 1 formula of
their own.

Conventions (REP 103 / REP 105, the same everywhere in the project):

- Frames are right-handed with x forward, y left, z up. `base_link` is the vehicle,
  `sonar` a sonar's acoustic centre (its fan is the x-y plane at elevation 0), `world`
  the map frame. `T_a_b` is the pose of frame b in frame a: it maps points given in
  b into a, p_a = T_a_b p_b, and T_a_c = T_a_b T_b_c.
- Angles are radians. Roll, pitch and yaw are fixed-axis (extrinsic) rotations about
  x, then y, then z: R = Rz(yaw) Ry(pitch) Rx(roll) (ROS RPY). A 6-vector pose is
  (x, y, z, roll, pitch, yaw) of a frame in its parent; a 2D pose is (x, y, yaw).
- Quaternions are (x, y, z, w), scalar last (ROS and scipy order). Where a canonical
  sign is needed (a quaternion computed from a matrix), w >= 0.
- Sonar coordinates (paper Eq. 1): range R [m], bearing theta [rad] positive left
  (towards +y), elevation phi [rad] positive up (towards +z):
  x = R cos(phi) cos(theta), y = R cos(phi) sin(theta), z = R sin(phi).
  An imaging sonar does not measure phi; its fan-plane points take phi = 0.

Conversions, Eq. 1 and the SE(3)/SE(2) constructors take arrays with any number of
leading dimensions (n, ...); `se3_apply`, `se2_apply` and `fan_in_frame` take one
transform and (n, d) points. Everything returns float64. Conversions go through
`scipy.spatial.transform.Rotation` where that gives the same bits as the arithmetic
the pipeline's stored artifacts were made with; the others are one closed form each,
checked against scipy to 1e-12 in tests/test_geometry.py. The simulator keeps its
matrix-product form of R = Rz Ry Rx (`matrix_from_rpy_product`), with which the
simulated recordings were made.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "fan_in_frame",
    "fan_to_xy",
    "matrix_from_quat",
    "matrix_from_rpy",
    "matrix_from_rpy_product",
    "polar_to_xyz",
    "pose_from_se3",
    "quat_from_matrix",
    "quat_from_rpy",
    "rpy_from_matrix",
    "rpy_from_quat",
    "se2",
    "se2_apply",
    "se3",
    "se3_apply",
    "se3_compose",
    "se3_from_pose",
    "se3_inverse",
    "xyz_to_polar",
]


def _f64(a: object) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def _rotation() -> Any:
    # Imported on first use: scipy.spatial.transform is slow to load,
    # which commands that never convert a rotation should not pay.
    from scipy.spatial.transform import Rotation

    return Rotation


# --- Eq. 1 -------------------------------------------------------------------------


def polar_to_xyz(range_m: object, bearing_rad: object, elevation_rad: object) -> np.ndarray:
    """(..., 3) sonar-frame points of (range, bearing, elevation) (paper Eq. 1).

    x = R cos(phi) cos(theta), y = R cos(phi) sin(theta), z = R sin(phi); the three
    inputs broadcast against each other.
    """
    r, th, phi = _f64(range_m), _f64(bearing_rad), _f64(elevation_rad)
    c = np.cos(phi)
    # (R cos phi) first: the order of the products fixes the last bit of every point.
    return np.stack([r * c * np.cos(th), r * c * np.sin(th), r * np.sin(phi)], axis=-1)


def xyz_to_polar(xyz: object) -> np.ndarray:
    """(..., 3) range, bearing, elevation of (..., 3) sonar-frame points (Eq. 1 inverted).

    R = |p|, theta = atan2(y, x), phi = asin(z / R); the origin maps to (0, 0, 0).
    """
    p = _f64(xyz)
    r = np.linalg.norm(p, axis=-1)
    phi = np.arcsin(np.clip(p[..., 2] / np.where(r > 0, r, 1.0), -1.0, 1.0))
    return np.stack([r, np.arctan2(p[..., 1], p[..., 0]), phi], axis=-1)


def fan_to_xy(range_m: object, bearing_rad: object) -> np.ndarray:
    """(..., 2) fan-plane points (x, y) of (range, bearing): Eq. 1 with phi = 0.

    x = R cos(theta), y = R sin(theta).
    """
    r, th = _f64(range_m), _f64(bearing_rad)
    return np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)


def fan_in_frame(range_m: object, bearing_rad: object, T_frame_sonar: object) -> np.ndarray:
    """(n, 3) points in another frame of n fan-plane returns (Eq. 1 with phi = 0).

    p_frame = T_frame_sonar (R cos(theta), R sin(theta), 0).
    """
    xy = fan_to_xy(np.ravel(range_m), np.ravel(bearing_rad))
    return se3_apply(T_frame_sonar, np.column_stack([xy, np.zeros(len(xy))]))


# --- SE(3) -------------------------------------------------------------------------


def se3(R: object, t: object) -> np.ndarray:
    """(..., 4, 4) homogeneous transforms [[R, t], [0, 1]] of (..., 3, 3) R and (..., 3) t."""
    R, t = _f64(R), _f64(t)
    lead = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*lead, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def se3_inverse(T: object) -> np.ndarray:
    """(..., 4, 4) inverses of rigid transforms: [[R^T, -R^T t], [0, 1]]."""
    T = _f64(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return se3(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def se3_compose(T_ab: object, T_bc: object) -> np.ndarray:
    """(..., 4, 4) T_ac = T_ab T_bc."""
    return _f64(T_ab) @ _f64(T_bc)


def se3_apply(T_ab: object, points_b: object) -> np.ndarray:
    """(n, 3) points p_a = R p_b + t of (n, 3) points given in frame b.

    Computed as the homogeneous product [p_b, 1] T_ab^T.
    """
    p = _f64(points_b).reshape(-1, 3)
    h = np.column_stack([p, np.ones(len(p))])
    return (h @ _f64(T_ab).T)[:, :3]


def se3_from_pose(pose: object) -> np.ndarray:
    """(..., 4, 4) transforms of (..., 6) poses (x, y, z, roll, pitch, yaw)."""
    p = _f64(pose)
    return se3(matrix_from_rpy(p[..., 3:6]), p[..., :3])


def pose_from_se3(T: object) -> np.ndarray:
    """(..., 6) poses (x, y, z, roll, pitch, yaw) of (..., 4, 4) transforms."""
    T = _f64(T)
    return np.concatenate([T[..., :3, 3], rpy_from_matrix(T[..., :3, :3])], axis=-1)


# --- SE(2) -------------------------------------------------------------------------


def se2(x: object, y: object, yaw: object) -> np.ndarray:
    """(..., 3, 3) homogeneous 2D transforms [[cos, -sin, x], [sin, cos, y], [0, 0, 1]]."""
    x, y, yaw = np.broadcast_arrays(_f64(x), _f64(y), _f64(yaw))
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.zeros((*yaw.shape, 3, 3))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = c, -s, x
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2] = s, c, y
    T[..., 2, 2] = 1.0
    return T


def se2_apply(T_ab: object, points_b: object) -> np.ndarray:
    """(n, 2) points p_a = R p_b + t of (n, 2) points given in frame b."""
    T = _f64(T_ab)
    return _f64(points_b).reshape(-1, 2) @ T[:2, :2].T + T[:2, 2]


# --- rotations ---------------------------------------------------------------------


def matrix_from_rpy(rpy: object) -> np.ndarray:
    """(..., 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll) of (..., 3) roll, pitch, yaw.

    Closed form: scipy's `Rotation.from_euler("xyz", rpy).as_matrix()` goes through a
    quaternion and differs in the last bit, which would move every stored pose.
    """
    a = _f64(rpy)
    cr, sr = np.cos(a[..., 0]), np.sin(a[..., 0])
    cp, sp = np.cos(a[..., 1]), np.sin(a[..., 1])
    cy, sy = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def matrix_from_rpy_product(rpy: object) -> np.ndarray:
    """(..., 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll), as the matrix product of the
    three elementary rotations.

    The same rotation as `matrix_from_rpy` (to 1e-15), in the simulator's arithmetic: the
    product leaves other signs on zero entries and other last bits, and the simulated
    recordings (their odometry quaternions) were made with it, so the simulator keeps it
    and its output stays byte-identical for a given SIM_VERSION.
    """
    a = _f64(rpy)
    lead = a.shape[:-1]
    flat = a.reshape(-1, 3)
    out = np.empty((len(flat), 3, 3))
    for n, (roll, pitch, yaw) in enumerate(flat.tolist()):
        # One 3x3 product per rotation, as the simulator always computed it: a stacked
        # matmul may take another summation path and other bits.
        cr, sr = np.cos(roll), np.sin(roll)
        cp, sp = np.cos(pitch), np.sin(pitch)
        cy, sy = np.cos(yaw), np.sin(yaw)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        out[n] = rz @ ry @ rx
    return out.reshape(*lead, 3, 3)


def rpy_from_matrix(R: object) -> np.ndarray:
    """(..., 3) roll, pitch, yaw of (..., 3, 3) rotations R = Rz(yaw) Ry(pitch) Rx(roll).

    roll = atan2(R21, R22), pitch = asin(-R20), yaw = atan2(R10, R00); pitch in
    [-pi/2, pi/2]. Closed form: scipy's `as_euler` goes through a quaternion (other
    bits, and yaw = 0 at gimbal lock where this keeps atan2's answer).
    """
    R = _f64(R)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def quat_from_rpy(rpy: object) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) of (..., 3) roll, pitch, yaw.

    The product q = qz(yaw) qy(pitch) qx(roll) of the half-angle quaternions, not sign
    canonicalised (w < 0 where the angles ask for it).
    """
    a = _f64(rpy)
    q = _rotation().from_euler("xyz", a.reshape(-1, 3)).as_quat()
    return np.asarray(q.reshape(*a.shape[:-1], 4), dtype=np.float64)


def rpy_from_quat(q_xyzw: object) -> np.ndarray:
    """(..., 3) roll, pitch, yaw of (..., 4) quaternions (x, y, z, w), normalised first.

    roll = atan2(2 (w x + y z), 1 - 2 (x^2 + y^2)), pitch = asin(2 (w y - z x)),
    yaw = atan2(2 (w z + x y), 1 - 2 (y^2 + z^2)). Closed form (scipy's `as_euler`
    gives other bits). A zero quaternion gives NaN angles.
    """
    q = _f64(q_xyzw)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def matrix_from_quat(q_xyzw: object) -> np.ndarray:
    """(..., 3, 3) rotations of (..., 4) quaternions (x, y, z, w), normalised first.

    Raises:
        ValueError: a quaternion of zero or non-finite norm.
    """
    q = _f64(q_xyzw)
    flat = q.reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(flat, axis=1)
    if not np.all(np.isfinite(norm) & (norm > 0)):
        raise ValueError("quaternion of zero or non-finite norm")
    R = _rotation().from_quat(flat).as_matrix()
    return np.asarray(R.reshape(*q.shape[:-1], 3, 3), dtype=np.float64)


def quat_from_matrix(R: object) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w), w >= 0, of (..., 3, 3) rotations.

    Shepperd's method: from the trace when it is positive, else from the largest
    diagonal element, then normalised. Closed form: scipy's `from_matrix` picks its
    branch differently and gives other bits, which would change simulated recordings.
    """
    m = _f64(R)
    lead = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    n = len(m)
    q = np.zeros((n, 4))
    tr = np.trace(m, axis1=1, axis2=2)
    pos = tr > 0
    if np.any(pos):
        mp = m[pos]
        s = 2.0 * np.sqrt(tr[pos] + 1.0)
        q[pos, 0] = (mp[:, 2, 1] - mp[:, 1, 2]) / s
        q[pos, 1] = (mp[:, 0, 2] - mp[:, 2, 0]) / s
        q[pos, 2] = (mp[:, 1, 0] - mp[:, 0, 1]) / s
        q[pos, 3] = s / 4
    rows = np.flatnonzero(~pos)
    if rows.size:
        mn = m[rows]
        i = np.argmax(np.diagonal(mn, axis1=1, axis2=2), axis=1)
        j, k = (i + 1) % 3, (i + 2) % 3
        at = np.arange(rows.size)
        s = 2.0 * np.sqrt(1.0 + mn[at, i, i] - mn[at, j, j] - mn[at, k, k])
        q[rows, 3] = (mn[at, k, j] - mn[at, j, k]) / s
        q[rows, i] = s / 4
        q[rows, j] = (mn[at, j, i] + mn[at, i, j]) / s
        q[rows, k] = (mn[at, k, i] + mn[at, i, k]) / s
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(*lead, 4)
