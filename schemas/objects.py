"""Column contract of the classify stage: `objects.parquet` and `object_features.parquet`.

One `objects` row per DBSCAN cluster of horizontal-sonar features that has at least
`min_features` members (paper Sec. IV.C). Geometry is in the horizontal sonar's
frame (REP 103, x forward, y left) projected onto its fan plane (elevation unknown):
x = R cos(theta), y = R sin(theta).
"""

from __future__ import annotations

import pyarrow as pa

__all__ = ["OBJECTS_SCHEMA", "OBJECT_FEATURES_SCHEMA", "UNKNOWN_CLASS_ID"]

UNKNOWN_CLASS_ID = -1
"""`class_id` of an object whose Monte-Carlo mean probability is below the threshold."""

OBJECTS_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("object_id", pa.int64(), nullable=False),
        pa.field("class_id", pa.int64(), nullable=False),
        pa.field("class_name", pa.string(), nullable=False),
        pa.field("argmax_class_name", pa.string(), nullable=False),
        pa.field("probability", pa.float64(), nullable=False),
        pa.field("probability_var", pa.float64(), nullable=False),
        pa.field("single_view_probability", pa.float64(), nullable=False),
        pa.field("n_views", pa.int64(), nullable=False),
        pa.field("n_features", pa.int64(), nullable=False),
        pa.field("x_m", pa.float64(), nullable=False),
        pa.field("y_m", pa.float64(), nullable=False),
        pa.field("range_m", pa.float64(), nullable=False),
        pa.field("bearing_rad", pa.float64(), nullable=False),
        pa.field("x_min_m", pa.float64(), nullable=False),
        pa.field("x_max_m", pa.float64(), nullable=False),
        pa.field("y_min_m", pa.float64(), nullable=False),
        pa.field("y_max_m", pa.float64(), nullable=False),
        pa.field("true_class_name", pa.string(), nullable=True),
    ]
)
"""objects.parquet, sorted by (keyframe_id, object_id); object_id is unique over the run.

- class_id / class_name: `sonarmap.schemas.classes` id and name of the accepted class, or
  -1 / "unknown" when the (pooled) mean probability is not above the threshold.
- argmax_class_name: the class of the largest (pooled) mean probability, accepted or not.
- probability: that class's mean softmax output over the m dropout passes, pooled over
  the object's n_views sightings in nearby keyframes (`sonarmap.stages.classify.view_pooling`) when
  `classify.pool_views` is on; single_view_probability / probability_var: mean and
  variance over this keyframe's m passes alone, of the same class.
- n_views: sightings pooled into `probability` (1: this keyframe's alone).
- n_features: cluster size; x_m, y_m: feature centroid [m]; range_m, bearing_rad: the
  centroid in polar form [m, rad]; x/y min/max: the features' bounding box [m], no margin.
- true_class_name: majority label-image class of the cluster's cells ("none" when most
  cells are unlabelled); null when the dataset has no label images.
"""

OBJECT_FEATURES_SCHEMA = pa.schema(
    [
        pa.field("keyframe_id", pa.int64(), nullable=False),
        pa.field("object_id", pa.int64(), nullable=False),
        pa.field("feature_id", pa.int64(), nullable=False),
    ]
)
"""object_features.parquet: which `features.parquet` row (feature_id) belongs to which
object; sorted by (keyframe_id, object_id, feature_id). Features in no kept cluster
(DBSCAN noise, small clusters) have no row."""
