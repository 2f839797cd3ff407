"""The classifier's view-agreement check: fewer objects accepted pooled over their views
than in single views means the views disagree, and the run warns (issue 50). The rule's
measurement on the benchmark's missions is in docs/classifier.md."""

from __future__ import annotations

import numpy as np

from sonarmap.stages.classify.acceptance import MIN_OBJECTS, acceptance_report

METRICS = {"accepted_fraction": 0.61, "threshold": 0.99}


def _single(n: int, sure: int) -> np.ndarray:
    p = np.full(n, 0.8)
    p[:sure] = 0.995
    return p


def test_views_that_agree_are_not_warned() -> None:
    got = acceptance_report(_single(200, 100), 130, METRICS, 0.99)
    assert got["sure_fraction"] == 0.5 and got["pooled_sure_fraction"] == 0.65
    assert got["validation_sure_fraction"] == 0.61 and got["validation_threshold"] == 0.99
    assert got["warnings"] == []
    # as many pooled as single (pool_views off gives exactly this): no warning
    assert acceptance_report(_single(200, 100), 100, METRICS, 0.99)["warnings"] == []


def test_fewer_pooled_than_single_view_acceptances_warn_with_both_shares() -> None:
    got = acceptance_report(_single(200, 76), 44, METRICS, 0.99)
    (line,) = got["warnings"]
    assert "22% of 200 objects" in line and "38% in single views" in line


def test_the_threshold_is_classifys() -> None:
    p = _single(200, 0)
    p[:150] = 0.95  # sure at 0.9, not at 0.99
    assert acceptance_report(p, 100, METRICS, 0.9)["warnings"]  # 0.50 < 0.75
    assert acceptance_report(p, 100, METRICS, 0.99)["warnings"] == []  # 0.50 > 0.0


def test_too_few_objects_or_no_cnn_are_not_warned() -> None:
    few = _single(MIN_OBJECTS - 1, MIN_OBJECTS - 1)
    assert acceptance_report(few, 0, METRICS, 0.99)["warnings"] == []
    assert acceptance_report(_single(MIN_OBJECTS, MIN_OBJECTS), 0, None, 0.99)["warnings"]
    oracle = acceptance_report(None, 0, METRICS, 0.99)
    assert oracle["objects"] == 0 and oracle["sure_fraction"] is None
    assert oracle["warnings"] == []


def test_a_compact_class_seen_from_one_keyframe_only_stays_unknown() -> None:
    """`classify.min_views`: a piling (object frame) is a fixed place, so another keyframe
    sees it again; a cluster no other keyframe sees (the grain's own detections) is not
    accepted as one, however sure the CNN is. A wall (beam frame) is not held to it: its
    clusters' centroids move along it with the viewpoint."""
    from sonarmap.stages.classify.class_columns import class_columns

    names = ["cylindrical_piling", "seawall"]
    pooled = np.array([[0.999, 0.001], [0.999, 0.001], [0.001, 0.999], [0.6, 0.4]])
    n_views = np.array([1, 2, 1, 5])
    args = (pooled, pooled, np.zeros_like(pooled), n_views, np.array([1, 3]), names, 0.99)
    compact = np.array([True, False])
    got = class_columns(*args, min_views=2, compact=compact)
    assert got["class_name"] == ["unknown", "cylindrical_piling", "seawall", "unknown"]
    assert list(got["argmax_class_name"]) == ["cylindrical_piling"] * 2 + ["seawall", "cylindrical_piling"]
    off = class_columns(*args, min_views=1, compact=compact)
    assert off["class_name"][:3] == ["cylindrical_piling", "cylindrical_piling", "seawall"]
    assert class_columns(*args)["class_name"] == off["class_name"]  # the rule's default: off
