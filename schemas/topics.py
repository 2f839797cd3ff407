"""Topic names, message type names and frame ids of the datasets sonarmap writes."""

from __future__ import annotations

__all__ = [
    "FRAME_BASE",
    "FRAME_ODOM",
    "FRAME_SONAR",
    "IMAGE_TYPE",
    "LABEL_TOPIC",
    "ODOMETRY_TYPE",
    "PROJECTED_SONAR_TYPE",
    "SONARS",
    "SONAR_TOPIC",
    "TOPIC_DEAD_RECKONING",
    "TOPIC_GROUND_TRUTH",
    "TOPIC_TF_STATIC",
    "TRUTH_ANGLE_TOPIC",
]

SONARS: tuple[str, str] = ("horizontal", "vertical")

PROJECTED_SONAR_TYPE = "marine_acoustic_msgs/msg/ProjectedSonarImage"
IMAGE_TYPE = "sensor_msgs/msg/Image"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"

SONAR_TOPIC = {s: f"/sonar/{s}" for s in SONARS}
LABEL_TOPIC = {s: f"/sonar/{s}/labels" for s in SONARS}
"""mono8 label image, same shape as the sonar image: class id per (range bin, beam)."""
TRUTH_ANGLE_TOPIC = {s: f"/sonar/{s}/truth_angle" for s in SONARS}
"""32FC1 image: true elevation (horizontal sonar) or bearing (vertical sonar) [rad], NaN = none."""

TOPIC_DEAD_RECKONING = "/odometry/dead_reckoning"
TOPIC_GROUND_TRUTH = "/ground_truth/odometry"
TOPIC_TF_STATIC = "/tf_static"

FRAME_ODOM = "odom"
FRAME_BASE = "base_link"
FRAME_SONAR = {s: f"sonar_{s}" for s in SONARS}
