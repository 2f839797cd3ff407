"""Column contracts of the `slam` stage: `poses.parquet` and `factors.parquet`.

Poses are the vehicle's base_link in the world (odom) frame, one row per keyframe, sorted
by keyframe_id. x, y, yaw come from the planar pose graph (or dead reckoning / ground
truth, by mode); z, roll, pitch come from the navigation stream. The covariance columns
are the iSAM2 marginal covariance of (x, y, yaw) in the body frame (GTSAM's Pose2
convention); all zero in ground-truth mode.

Factors are every constraint the front end considered, accepted or not, in the order
they were created.
"""

from __future__ import annotations

import pyarrow as pa

__all__ = [
    "COVARIANCE_COLUMNS",
    "FACTORS_SCHEMA",
    "FACTOR_STATUSES",
    "FACTOR_TYPES",
    "POSES_SCHEMA",
    "SLAM_MODES",
]

SLAM_MODES: tuple[str, ...] = ("slam", "dead_reckoning", "ground_truth")

COVARIANCE_COLUMNS: tuple[str, ...] = (
    "cov_xx_m2",
    "cov_xy_m2",
    "cov_xyaw_m_rad",
    "cov_yy_m2",
    "cov_yyaw_m_rad",
    "cov_yawyaw_rad2",
)
"""Upper triangle of the 3x3 (x, y, yaw) covariance, row by row."""

POSES_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("t_ns", pa.int64(), nullable=False),
        *[
            pa.field(c, pa.float64(), nullable=False)
            for c in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
        ],
        *[pa.field(c, pa.float64(), nullable=False) for c in COVARIANCE_COLUMNS],
    ]
)
"""poses.parquet: keyframe id, time [ns], base_link pose in the world frame [m, rad],
marginal covariance of (x, y, yaw) [m^2, m rad, rad^2]."""

FACTOR_TYPES: tuple[str, ...] = ("prior", "odometry", "heading", "ssm", "loop")
"""prior on the first pose; odometry (dead reckoning between consecutive keyframes);
heading (the navigation yaw as an absolute heading, key_from == key_to, x and y free);
ssm (sequential scan matching); loop (non-sequential scan matching, after PCM)."""

FACTOR_STATUSES: tuple[str, ...] = ("accepted", "rejected", "unused")
"""unused: an odometry factor that sequential scan matching replaced."""

FACTORS_SCHEMA = pa.schema(
    [
        pa.field("factor_id", pa.int64(), nullable=False),
        pa.field("type", pa.string(), nullable=False),
        pa.field("key_from", pa.int64(), nullable=False),
        pa.field("key_to", pa.int64(), nullable=False),
        pa.field("x_m", pa.float64(), nullable=False),
        pa.field("y_m", pa.float64(), nullable=False),
        pa.field("yaw_rad", pa.float64(), nullable=False),
        *[pa.field(c, pa.float64(), nullable=False) for c in COVARIANCE_COLUMNS],
        pa.field("status", pa.string(), nullable=False),
        pa.field("reason", pa.string(), nullable=False),
        pa.field("overlap_points", pa.int64(), nullable=False),
        pa.field("rmse_m", pa.float64(), nullable=True),
        pa.field("degenerate", pa.string(), nullable=False),
    ]
)
"""factors.parquet: factor id (creation order), type (FACTOR_TYPES), keyframe ids (the
measurement is the pose of key_to in the frame of key_from; key_from == key_to for the
prior and heading factors, whose measurement is the world pose), measurement [m, rad],
its covariance, status (FACTOR_STATUSES), reason (why rejected, or for an odometry factor
that was not used because scan matching replaced it (status "unused"); empty otherwise),
ICP overlap (source points with a target neighbour; 0 without scan matching), ICP
RMSE [m] and, for scan matches, the directions the match left unconstrained (its factor
free along them: "x", "y", "yaw" in the body frame, comma-separated; "" when none or not
a scan match; `sonarmap.stages.slam.degeneracy`)."""
