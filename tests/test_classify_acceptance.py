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


def test_a_compact_class_seldom_seen_where_the_fan_covered_it_stays_unknown() -> None:
    """`classify.min_seen_share`: a piling (object frame) is a fixed place, so the keyframes
    whose fan covers it mostly see it; a cluster they seldom see (the grain's own
    detections, a part of a hull) is not accepted as one, however sure the CNN is. A wall
    (beam frame) is not held to it: its clusters' centroids move along it with the
    viewpoint."""
    from sonarmap.stages.classify.class_columns import class_columns

    names = ["cylindrical_piling", "seawall"]
    pooled = np.array([[0.999, 0.001], [0.999, 0.001], [0.001, 0.999], [0.6, 0.4]])
    seen = np.array([0.1, 0.5, 0.1, 1.0])
    args = (pooled, pooled, np.zeros_like(pooled), np.array([2, 6, 1, 5]), np.array([1, 3]))
    compact = np.array([True, False])
    got = class_columns(*args, names, 0.99, 1, seen, 0.5, compact)
    assert got["class_name"] == ["unknown", "cylindrical_piling", "seawall", "unknown"]
    assert list(got["argmax_class_name"]) == [*["cylindrical_piling"] * 2, "seawall", "cylindrical_piling"]
    off = class_columns(*args, names, 0.99, 1, seen, 0.0, compact)
    assert off["class_name"][:3] == ["cylindrical_piling", "cylindrical_piling", "seawall"]
    assert class_columns(*args, names, 0.99)["class_name"] == off["class_name"]  # no rule
    # `classify.min_views` (the default, 2): the first piling pooled 2 sightings, so 3 holds
    # it back and 2 does not; the wall is never held.
    views = class_columns(*args, names, 0.99, 3, None, 0.0, compact)["class_name"]
    assert views[:3] == ["unknown", "cylindrical_piling", "seawall"]
    assert class_columns(*args, names, 0.99, 2, None, 0.0, compact)["class_name"] == off["class_name"]


def test_fan_coverage_counts_the_keyframes_whose_fan_holds_the_place() -> None:
    from sonarmap.stages.classify.view_pooling import fan_coverage

    # Three keyframes along x, the sonar looking ahead (+x), a 10-20 m, +-30 deg fan.
    sonar = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [30.0, 0.0, np.pi]])
    fans = np.tile([10.0, 20.0, -np.pi / 6, np.pi / 6], (3, 1))
    places = np.array([[18.0, 0.0], [18.0, 8.0], [100.0, 0.0]])
    along = np.array([0.0, 0.0, 0.0])
    got = fan_coverage(places, along, sonar, fans, np.array([0.0, 5.0, 30.0]), window_m=80.0)
    # (18, 0): 18 m ahead of the first, 13 m ahead of the second, 12 m ahead of the third
    # (which looks back); (18, 8): 24 deg off the first's axis, 32 and 34 deg off the others'.
    assert got.tolist() == [3, 1, 0]
    at = np.array([0.0, 5.0, 30.0])
    assert fan_coverage(places, along, sonar, fans, at, window_m=10.0).tolist() == [2, 1, 0]
    # A place must be wholly in view: (18, 0) is 2 m inside the first's far edge and 2 m
    # beyond the third's near one, so a 1 m margin keeps all three and a 2.5 m margin only
    # the second; (18, 8) is 19.7 m from the first, 0.3 m inside its far edge.
    assert fan_coverage(places, along, sonar, fans, at, 80.0, margin_m=1.0).tolist() == [3, 0, 0]
    assert fan_coverage(places, along, sonar, fans, at, 80.0, margin_m=2.5).tolist() == [1, 0, 0]
