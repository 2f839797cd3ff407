"""Training tells the truth: dropped classes, no validation, shapes over no feature (38.3)."""

from __future__ import annotations

import logging

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.schemas.annotations import AnnotationFile
from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.classify.annotations import label_keyframes, objects_without_features
from sonarmap.stages.classify.validation import say_what_is_not_learned

ANGLES = np.deg2rad(np.linspace(-60, 60, 64)).astype(np.float32)
RANGES = (np.arange(100) * 0.2 + 0.1).astype(np.float32)

ANNOTATIONS = AnnotationFile.model_validate(
    {
        "keyframes": [
            {
                "t_ns": 5,
                "objects": [
                    {"class_name": "seawall", "box_m": {
                        "x_min_m": 9, "x_max_m": 11, "y_min_m": -1, "y_max_m": 1}},
                    {"class_name": "truss", "box_m": {
                        "x_min_m": 9, "x_max_m": 11, "y_min_m": -11, "y_max_m": -9}},
                ],
            }
        ]
    }
)  # fmt: skip


def _frame(t_ns: int) -> KeyframeImages:
    ping = SonarPing(t_ns, "horizontal", np.zeros((100, 64), np.uint8), RANGES, ANGLES)
    return KeyframeImages(0, t_ns, ping, ping)


def test_a_shape_over_no_feature_is_found_and_named_in_a_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # One feature straight ahead at 10 m: inside the seawall box, nowhere near the truss.
    objects = ANNOTATIONS.keyframes[0].objects
    assert objects_without_features(objects, np.array([10.0]), np.array([0.0])) == [1]
    assert objects_without_features(objects, np.zeros(0), np.zeros(0)) == [0, 1]
    features = pa.table(
        {"keyframe_id": [0, 0], "sonar": ["horizontal", "vertical"],
         "range_m": [10.0, 14.0], "angle_rad": [0.0, -0.8]}
    )  # fmt: skip
    with caplog.at_level(logging.WARNING):
        out = list(label_keyframes([_frame(5)], ANNOTATIONS, source="a.yaml", features=features))
    assert len(out) == 1 and out[0].horizontal.labels is not None
    text = caplog.text
    assert "a.yaml: 1 annotated shapes hold no detected feature" in text
    assert "t_ns 5 object 1 (truss)" in text and "seawall" not in text


def test_every_class_left_out_and_an_empty_validation_are_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    wall, pile, truss = CLASS_IDS["seawall"], CLASS_IDS["cylindrical_piling"], CLASS_IDS["truss"]
    class_id = np.array([wall] * 12 + [pile] * 11 + [truss] * 4 + [wall] * 3)
    train = np.r_[np.ones(27, bool), np.zeros(3, bool)]
    with caplog.at_level(logging.WARNING):
        say_what_is_not_learned(class_id, train, ~train, [wall, pile], 10)
    assert "class truss: 4 training objects, under train.min_class_samples=10" in caplog.text
    said = " ".join(caplog.messages)  # the messages, not the logger's module name
    assert "seawall" not in said and "validation" not in said
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        say_what_is_not_learned(class_id, np.ones(30, bool), np.zeros(30, bool), [wall, pile], 10)
    assert "no validation object" in caplog.text and "unvalidated" in caplog.text
