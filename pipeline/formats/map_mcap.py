"""`map.mcap`: the voxelize stage's world-frame maps as ROS 2 messages for Foxglove.

Topics:
- `/map/standard`, `/map/semantic`: one `sensor_msgs/msg/PointCloud2` each in frame
  `map`, stamped at the last keyframe, fields x y z (float32, world frame [m]),
  `source` (uint8: 0 fused, 1 inferred) and `class_id` (uint8: `sonarmap.schemas.classes`
  ids, 0 for unclassified, 255 for "unknown"); point step 16 bytes, little-endian.
- `/tf`: one `tf2_msgs/msg/TFMessage` per keyframe, map -> base_link at the SLAM pose.

Same tables, same bytes (explicit times, no wall clock).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter, ros2_typestore
from sonarmap.schemas.classes import DEFAULT_TABLE, UNKNOWN_CLASS, ClassTable
from sonarmap.stages.kernels.geometry import quat_from_rpy

__all__ = [
    "FRAME_BASE",
    "FRAME_MAP",
    "MAP_TOPICS",
    "TF_TOPIC",
    "point_cloud_bytes",
    "write_map_mcap",
]

FRAME_MAP = "map"
FRAME_BASE = "base_link"
MAP_TOPICS: dict[str, str] = {"standard": "/map/standard", "semantic": "/map/semantic"}
TF_TOPIC = "/tf"
SOURCE_IDS: dict[str, int] = {"fused": 0, "inferred": 1}
UNKNOWN_CLASS_ID = 255
POINTFIELD_UINT8 = 2
POINTFIELD_FLOAT32 = 7
"""sensor_msgs/msg/PointField datatype constants."""

_POINT_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("source", "u1"), ("class_id", "u1"), ("pad", "<u2")]
)
"""One PointCloud2 record, 16 bytes; the padding is an explicit zero field so that copies
never carry uninitialised bytes into the file."""


def point_cloud_bytes(map_table: pa.Table, table: ClassTable = DEFAULT_TABLE) -> np.ndarray:
    """(n,) structured PointCloud2 records (x, y, z, source, class_id) of the map rows;
    class ids are those of the class table `table`."""
    rec = np.zeros(map_table.num_rows, dtype=_POINT_DTYPE)
    for c in ("x", "y", "z"):
        rec[c] = map_table.column(f"{c}_m").to_numpy()
    source = map_table.column("source").to_pylist()
    classes = map_table.column("class_name").to_pylist()
    rec["source"] = np.array([SOURCE_IDS.get(s, 255) for s in source], dtype=np.uint8)
    ids = {**table.ids, UNKNOWN_CLASS: UNKNOWN_CLASS_ID}
    rec["class_id"] = np.array([ids.get(c, UNKNOWN_CLASS_ID) for c in classes], dtype=np.uint8)
    return rec


def _stamp(t_ns: int) -> Any:
    return ros2_typestore().types["builtin_interfaces/msg/Time"](
        sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
    )


def _header(t_ns: int, frame: str) -> Any:
    return ros2_typestore().types["std_msgs/msg/Header"](stamp=_stamp(t_ns), frame_id=frame)


def _cloud(rec: np.ndarray, t_ns: int) -> Any:
    t = ros2_typestore().types
    field = t["sensor_msgs/msg/PointField"]
    fields = [
        field(name=n, offset=o, datatype=d, count=1)
        for n, o, d in (
            ("x", 0, POINTFIELD_FLOAT32),
            ("y", 4, POINTFIELD_FLOAT32),
            ("z", 8, POINTFIELD_FLOAT32),
            ("source", 12, POINTFIELD_UINT8),
            ("class_id", 13, POINTFIELD_UINT8),
        )
    ]
    return t["sensor_msgs/msg/PointCloud2"](
        header=_header(t_ns, FRAME_MAP),
        height=1,
        width=len(rec),
        fields=fields,
        is_bigendian=False,
        point_step=_POINT_DTYPE.itemsize,
        row_step=_POINT_DTYPE.itemsize * len(rec),
        data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def _tf(row: dict[str, Any], t_ns: int) -> Any:
    t = ros2_typestore().types
    q = quat_from_rpy([row["roll_rad"], row["pitch_rad"], row["yaw_rad"]]).tolist()
    transform = t["geometry_msgs/msg/Transform"](
        translation=t["geometry_msgs/msg/Vector3"](x=row["x_m"], y=row["y_m"], z=row["z_m"]),
        rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    stamped = t["geometry_msgs/msg/TransformStamped"](
        header=_header(t_ns, FRAME_MAP), child_frame_id=FRAME_BASE, transform=transform
    )
    return t["tf2_msgs/msg/TFMessage"](transforms=[stamped])


def write_map_mcap(map_table: pa.Table, poses: pa.Table, path: Path) -> int:
    """Write the maps and keyframe poses to a ROS 2 MCAP file.

    Args:
        map_table: map.parquet (`sonarmap.schemas.map.MAP_SCHEMA`), world frame.
        poses: poses.parquet (`sonarmap.schemas.slam.POSES_SCHEMA`: keyframe_id, t_ns, pose).
        path: output file (overwritten).

    Returns:
        The number of messages written.
    """
    rows = poses.sort_by([("t_ns", "ascending"), ("keyframe_id", "ascending")]).to_pylist()
    t_map = int(rows[-1]["t_ns"]) if rows else 0
    rec = point_cloud_bytes(map_table)
    fused = rec["source"] == SOURCE_IDS["fused"]
    n = 0
    with path.open("wb") as stream, Ros2McapWriter(stream) as writer:
        writer.add_metadata(
            "sonarmap_map",
            {
                "points_fused": str(int(fused.sum())),
                "points_total": str(len(rec)),
                "frame": FRAME_MAP,
            },
        )
        for row in rows:
            writer.write(
                TF_TOPIC, "tf2_msgs/msg/TFMessage", _tf(row, int(row["t_ns"])), int(row["t_ns"])
            )
            n += 1
        for name, cloud in (("standard", rec[fused]), ("semantic", rec)):
            writer.write(
                MAP_TOPICS[name], "sensor_msgs/msg/PointCloud2", _cloud(cloud, t_map), t_map
            )
            n += 1
    return n
