"""Objects of one horizontal image: DBSCAN clusters, boxes, aspect-preserving crops."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.schemas.sonar import SonarPing
from sonarmap.stages.classify.objects import (
    crop_patches,
    extract_objects,
    horizontal_features,
    los_rotate,
    row_background,
)
from sonarmap.stages.classify.segmentation import (
    cell_areas_m2,
    cluster_boxes,
    fan_outside_area_m2,
    keep_clusters,
    majority_class,
)
from sonarmap.stages.classify.sensor_noise import noisy_image
from sonarmap.stages.kernels.clustering import cluster_features

RANGES_M = ((np.arange(400) + 0.5) * 0.05).astype(np.float32)


def _polar_of_rect(
    angles_rad: np.ndarray, x0: float, x1: float, y0: float, y1: float
) -> np.ndarray:
    """Polar uint8 image whose cells are 255 inside the Cartesian rectangle, else 0."""
    r = RANGES_M[:, None].astype(np.float64)
    a = angles_rad[None, :].astype(np.float64)
    x, y = r * np.cos(a), r * np.sin(a)
    inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    return np.where(inside, 255, 0).astype(np.uint8)


def test_dbscan_keeps_clusters_of_min_features_and_numbers_them_in_order() -> None:
    rng = np.random.default_rng(0)
    blob_a = rng.normal([5.0, 1.0], 0.05, (30, 2))
    blob_b = rng.normal([8.0, -2.0], 0.05, (20, 2))
    small = rng.normal([3.0, 3.0], 0.02, (4, 2))
    noise = np.array([[1.0, -4.0], [12.0, 6.0], [6.0, 5.0]])
    xy = np.concatenate([blob_b, noise, blob_a, small])
    labels = cluster_features(xy, eps_m=0.25, min_samples=2, min_features=10)
    assert set(labels[:20]) == {0}  # blob_b comes first
    assert set(labels[20:23]) == {-1}
    assert set(labels[23:53]) == {1}
    assert set(labels[53:]) == {-1}  # 4 < min_features
    assert len(cluster_features(np.zeros((0, 2)), 0.25, 2, 10)) == 0


def test_cluster_boxes_match_a_reference_loop() -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform(-5, 5, (200, 2))
    labels = rng.integers(-1, 6, 200)
    boxes = cluster_boxes(xy, labels, 6)
    for k in range(6):
        p = xy[labels == k]
        np.testing.assert_allclose(
            boxes[k], [p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()]
        )


def test_majority_class_counts_the_cells_of_each_object() -> None:
    label_image = np.zeros((10, 10), np.uint8)
    label_image[0, :6] = 1
    label_image[1, :] = 2
    rb = np.array([0, 0, 0, 1, 1, 1, 1, 2, 2, 0])
    bm = np.array([0, 1, 7, 0, 1, 2, 3, 0, 1, 2])
    obj = np.array([0, 0, 0, 1, 1, 1, 1, 2, 2, -1])
    np.testing.assert_array_equal(majority_class(label_image, rb, bm, obj, 3), [1, 2, 0])


@pytest.mark.parametrize("uneven", [False, True])
def test_crop_preserves_aspect_ratio_and_pads_outside_the_box(uneven: bool) -> None:
    angles = np.linspace(-1.1, 1.1, 512)
    if uneven:  # denser beams near the centre: the angle table, not its spacing, must be used
        angles = 1.1 * np.sign(angles) * np.abs(angles / 1.1) ** 1.5
    angles = angles.astype(np.float32)
    # A 1.0 m (forward) x 0.25 m (across) bright rectangle at 10 m straight ahead.
    image = _polar_of_rect(angles, 9.5, 10.5, -0.125, 0.125)
    box = np.array([[9.5, 10.5, -0.125, 0.125]])
    patch = crop_patches(image, RANGES_M, angles, box, margin_m=0.1, size_px=40)[0]
    assert patch.shape == (40, 40) and patch.dtype == np.float32
    assert patch.max() == pytest.approx(1.0)
    bright = patch > 0.5
    rows = np.flatnonzero(bright.any(axis=1))
    cols = np.flatnonzero(bright.any(axis=0))
    height, width = np.ptp(rows) + 1, np.ptp(cols) + 1
    # Square side = 1.0 + 2 * 0.1 m over 40 px: the rectangle spans ~33 x ~8 px.
    assert height == pytest.approx(40 * 1.0 / 1.2, abs=2)
    assert width == pytest.approx(40 * 0.25 / 1.2, abs=2)
    assert abs((cols.min() + cols.max()) / 2 - 19.5) <= 1.0
    # Outside the box grown by its margin (0.1 m = 3.3 px) everything is padding.
    assert not patch[:, : int(cols.min() - 5)].any()
    assert not patch[:, int(cols.max() + 6) :].any()


def test_background_normalised_patch_ignores_the_sensors_noise_floor() -> None:
    """The same object on a dark and on a bright, speckled floor: peak-normalised patches
    differ wholesale (the floor becomes a grey patch), background-normalised ones agree."""
    angles = np.linspace(-1.1, 1.1, 512).astype(np.float32)
    clean = _polar_of_rect(angles, 9.8, 10.2, -0.1, 0.1) // 2  # an object at level 127
    rng = np.random.default_rng(3)
    floor = rng.weibull(1.2, clean.shape) * 45.0  # Oculus-like: median ~33, heavy tail
    bright = np.minimum(clean + floor + 0.5, 255).astype(np.uint8)
    box = np.array([[9.8, 10.2, -0.1, 0.1]])
    kw: dict[str, Any] = {"margin_m": 0.3, "min_side_m": 1.0}
    peak = [crop_patches(im, RANGES_M, angles, box, **kw)[0] for im in (clean, bright)]
    norm = [
        crop_patches(im, RANGES_M, angles, box, background=row_background(im), **kw)[0]
        for im in (clean, bright)
    ]
    for p in norm:
        assert p.dtype == np.float32 and p.min() >= 0.0 and p.max() <= 1.0
    # The object's pixels stay near 1 and the floor near 0 only after normalisation.
    obj = norm[0] > 0.5
    assert obj.sum() > 50
    assert np.median(norm[1][~obj]) < 0.05
    assert np.median(peak[1][~obj]) > 0.1
    assert np.abs(norm[1] - norm[0]).mean() < 0.7 * np.abs(peak[1] - peak[0]).mean()
    # row_background: the per-range median over beams, i.e. the floor, not the object.
    assert np.all(row_background(clean) == 0)
    assert np.median(row_background(bright)) == pytest.approx(np.median(bright), abs=3)



def test_grain_normalisation_darkens_grain_correlated_across_beams() -> None:
    """Grain correlated across beams (the real Oculus ping's) leaves blobs above the row
    median as bright as the object; above the row's 90th percentile ("grain") they go
    dark and the object stays."""
    from scipy.ndimage import uniform_filter1d

    from sonarmap.stages.classify.objects import GRAIN_QUANTILE

    angles = np.linspace(-1.1, 1.1, 512).astype(np.float32)
    obj_img = _polar_of_rect(angles, 9.8, 10.2, -0.1, 0.1)
    rng = np.random.default_rng(5)
    field = uniform_filter1d(rng.standard_normal(obj_img.shape), 6, axis=1) * 6**0.5
    grain = 40.0 * np.exp(0.6 * field)  # log-normal grain, blobs ~6 beams wide
    image = np.minimum(np.maximum(obj_img, grain), 255).astype(np.uint8)
    box = np.array([[9.8, 10.2, -0.1, 0.1]])
    kw: dict[str, Any] = {"margin_m": 0.3, "min_side_m": 1.0}
    clean = crop_patches(obj_img, RANGES_M, angles, box, **kw)[0]
    median, upper = (
        crop_patches(image, RANGES_M, angles, box, background=row_background(image, q), **kw)[0]
        for q in (0.5, GRAIN_QUANTILE)
    )
    obj = clean > 0.5
    assert obj.sum() > 50
    assert np.median(upper[obj]) > 0.9  # the object stays white
    bright_floor = [float((p[~obj] > 0.3).mean()) for p in (median, upper)]
    assert bright_floor[1] < 0.5 * bright_floor[0], bright_floor
    assert np.all(row_background(image, GRAIN_QUANTILE) >= row_background(image))

def test_noisy_image_is_seeded_and_spans_its_noise_levels() -> None:
    image = np.zeros((200, 100), np.uint8)
    image[50:60] = 200
    a = noisy_image(image, (2.0, 128.0), (0.9, 4.5), (0, 1, 2, 3))
    np.testing.assert_array_equal(a, noisy_image(image, (2.0, 128.0), (0.9, 4.5), (0, 1, 2, 3)))
    assert a.dtype == np.uint8 and (a[50:60] >= 200).all()  # added, never taken away
    means = [noisy_image(image, (10.0, 10.0), (2.0, 2.0), (s,))[100:].mean() for s in range(3)]
    assert means == pytest.approx([10.0] * 3, abs=1.0)  # the drawn mean level is the mean
    levels = {int(np.median(noisy_image(image, (2.0, 128.0), (2.0, 2.0), (s,)))) for s in range(8)}
    assert len(levels) > 4  # different copies, different floors


def test_line_of_sight_crop_looks_the_same_at_any_bearing() -> None:
    angles = np.linspace(-1.1, 1.1, 1024).astype(np.float32)
    # The same 1.0 x 0.25 m rectangle, seen straight ahead and at a 40 degree bearing,
    # built as a set of dense features so the rotated image is exact in the LOS frame.
    uv = np.stack(np.meshgrid(np.linspace(9.5, 10.5, 60), np.linspace(-0.125, 0.125, 15)), -1)
    uv = uv.reshape(-1, 2)
    patches = []
    for bearing in (0.0, np.deg2rad(40.0)):
        xy = los_rotate(uv, np.full(len(uv), -bearing))  # LOS -> sonar frame
        r, a = np.hypot(xy[:, 0], xy[:, 1]), np.arctan2(xy[:, 1], xy[:, 0])
        image = np.zeros((len(RANGES_M), len(angles)), np.uint8)
        image[np.searchsorted(RANGES_M, r), np.searchsorted(angles, a)] = 255
        box = np.array([[9.5, 10.5, -0.125, 0.125]])
        patches.append(
            crop_patches(image, RANGES_M, angles, box, np.array([bearing]), margin_m=0.1)[0]
        )
    cols = [np.flatnonzero((p > 0.3).any(axis=0)) for p in patches]
    rows = [np.flatnonzero((p > 0.3).any(axis=1)) for p in patches]
    assert abs(np.ptp(cols[0]) - np.ptp(cols[1])) <= 2
    assert abs(np.ptp(rows[0]) - np.ptp(rows[1])) <= 2
    assert np.ptp(cols[1]) < np.ptp(rows[1]) / 2  # still tall and thin, not rotated by 40 deg


def test_extract_objects_on_two_targets_with_labels() -> None:
    angles = np.linspace(-1.1, 1.1, 512).astype(np.float32)
    image = _polar_of_rect(angles, 6.0, 6.4, 1.0, 1.4) | _polar_of_rect(
        angles, 12.0, 12.3, -3.0, -2.0
    )
    labels = np.where(_polar_of_rect(angles, 6.0, 6.4, 1.0, 1.4) > 0, 1, 0).astype(np.uint8)
    labels |= np.where(_polar_of_rect(angles, 12.0, 12.3, -3.0, -2.0) > 0, 2, 0).astype(np.uint8)
    ping = SonarPing(0, "horizontal", image, RANGES_M, angles, labels=labels)
    rb, bm = np.nonzero(image)
    rb = np.concatenate([rb, [50, 300]])  # two isolated noise cells
    bm = np.concatenate([bm, [10, 400]])
    objs = extract_objects(
        ping, rb, bm, RANGES_M[rb], angles[bm],
        eps_m=0.25, min_samples=2, min_features=10, margin_m=0.2, min_side_m=0.5,
    )  # fmt: skip
    assert objs.count == 2
    np.testing.assert_array_equal(objs.true_class_id, [1, 2])
    np.testing.assert_allclose(objs.centroid_xy, [[6.2, 1.2], [12.15, -2.5]], atol=0.06)
    np.testing.assert_allclose(objs.boxes[0], [6.0, 6.4, 1.0, 1.4], atol=0.06)
    assert objs.n_features.sum() == len(rb) - 2
    assert len(objs.feature_index) == len(rb) - 2
    assert objs.patches.shape == (2, 40, 40)


def test_horizontal_features_splits_by_keyframe_and_drops_vertical_rows() -> None:
    table = pa.table(
        {
            "keyframe_id": pa.array([3, 1, 1, 3, 1], pa.int64()),
            "feature_id": pa.array([7, 2, 1, 5, 0], pa.int64()),
            "sonar": ["horizontal", "horizontal", "horizontal", "vertical", "vertical"],
            "range_bin": pa.array([1, 2, 3, 4, 5], pa.int64()),
            "beam": pa.array([1, 2, 3, 4, 5], pa.int64()),
            "range_m": [1.0, 2.0, 3.0, 4.0, 5.0],
            "angle_rad": [0.1, 0.2, 0.3, 0.4, 0.5],
            "intensity": pa.array([9, 9, 9, 9, 9], pa.uint8()),
        }
    )
    split = horizontal_features(table)
    assert sorted(split) == [1, 3]
    np.testing.assert_array_equal(split[1]["feature_id"], [1, 2])
    np.testing.assert_array_equal(split[1]["range_bin"], [3, 2])
    np.testing.assert_array_equal(split[3]["feature_id"], [7])
    with pytest.raises(ValueError, match="range_m"):
        horizontal_features(table.drop(["range_m"]))


def test_linked_components_match_scikit_learn_dbscan() -> None:
    from sklearn.cluster import DBSCAN

    rng = np.random.default_rng(3)
    centres = rng.uniform(-10, 10, (25, 2))
    xy = np.concatenate(
        [rng.normal(c, rng.uniform(0.02, 0.3), (rng.integers(1, 40), 2)) for c in centres]
    )
    xy = np.concatenate([xy, rng.uniform(-12, 12, (60, 2))])[rng.permutation(len(xy) + 60)]
    for min_samples in (1, 2, 3):
        for min_features in (1, 5, 10):
            ours = cluster_features(xy, 0.25, min_samples, min_features)
            raw = DBSCAN(eps=0.25, min_samples=min_samples).fit_predict(xy)
            # Same partition: the same points are noise, and labels map one-to-one.
            sizes = np.bincount(raw[raw >= 0])
            kept = (raw >= 0) & (sizes[np.maximum(raw, 0)] >= min_features)
            np.testing.assert_array_equal(ours >= 0, kept)
            pairs = set(zip(ours[kept].tolist(), raw[kept].tolist(), strict=True))
            assert len(pairs) == len({a for a, _ in pairs}) == len({b for _, b in pairs})


# --- Cluster rules of the original's simulation code (reference Sec. 4.1 step 5) ----------

FAN_RANGES_M = ((np.arange(600) + 0.5) * 0.05).astype(np.float32)
FAN_ANGLES = np.deg2rad(-65 + 130 * (np.arange(512) + 0.5) / 512).astype(np.float32)


def covered_area_m2(
    ranges_m: np.ndarray, angles_rad: np.ndarray, rb: np.ndarray, bm: np.ndarray, pixel_m: float
) -> float:
    """Independent check of a cell set's area: the fine Cartesian pixels whose centres fall
    in one of its cells (each cell bounded by the midpoints of the range / beam tables)."""
    r = ranges_m.astype(np.float64)
    a = angles_rad.astype(np.float64)
    r_edges = np.r_[r[0] - (r[1] - r[0]) / 2, (r[1:] + r[:-1]) / 2, r[-1] + (r[-1] - r[-2]) / 2]
    a_edges = np.r_[a[0] - (a[1] - a[0]) / 2, (a[1:] + a[:-1]) / 2, a[-1] + (a[-1] - a[-2]) / 2]
    rr, aa = np.meshgrid(r_edges[[rb.min(), rb.max() + 1]], a_edges[[bm.min(), bm.max() + 1]])
    xs, ys = rr * np.cos(aa), rr * np.sin(aa)
    x0 = min(xs.min(), r_edges[rb.min()] * np.cos(a_edges[[bm.min(), bm.max() + 1]]).min())
    x1 = r_edges[rb.max() + 1]
    gx = np.arange(x0 - pixel_m, x1 + pixel_m, pixel_m)
    gy = np.arange(ys.min() - pixel_m, ys.max() + pixel_m, pixel_m)
    x, y = np.meshgrid(gx + pixel_m / 2, gy + pixel_m / 2)
    ib = np.searchsorted(r_edges, np.hypot(x, y)) - 1
    jb = np.searchsorted(a_edges, np.arctan2(y, x)) - 1
    inside = (ib >= 0) & (ib < len(r)) & (jb >= 0) & (jb < len(a))
    cells = np.isin(ib * len(a) + jb, rb * len(a) + bm) & inside
    return float(cells.sum() * pixel_m**2)


@pytest.mark.parametrize("uneven", [False, True])
def test_cell_areas_are_the_cartesian_area_the_cells_cover(uneven: bool) -> None:
    angles = np.linspace(-1.1, 1.1, 512)
    if uneven:
        angles = 1.1 * np.sign(angles) * np.abs(angles / 1.1) ** 1.5
    angles = angles.astype(np.float32)
    for rect in ((6.0, 6.4, 1.0, 1.4), (12.0, 12.3, -3.0, -2.0), (3.0, 3.6, -0.4, 0.4)):
        rb, bm = np.nonzero(_polar_of_rect(angles, *rect))
        area = cell_areas_m2(RANGES_M, angles, rb, bm).sum()
        assert area == pytest.approx(covered_area_m2(RANGES_M, angles, rb, bm, 0.004), rel=0.02)
        true = (rect[1] - rect[0]) * (rect[3] - rect[2])
        assert area == pytest.approx(true, rel=0.15)  # cells with centres inside the box


def _two_targets(angles: np.ndarray) -> tuple[SonarPing, np.ndarray, np.ndarray]:
    small = _polar_of_rect(angles, 6.0, 6.4, 1.0, 1.4)  # 0.16 m2
    large = _polar_of_rect(angles, 12.0, 12.3, -3.0, -2.0)  # 0.30 m2
    labels = np.where(small > 0, 1, 0).astype(np.uint8) | np.where(large > 0, 2, 0).astype(np.uint8)
    ping = SonarPing(0, "horizontal", small | large, RANGES_M, angles, labels=labels)
    rb, bm = np.nonzero(small | large)
    return ping, rb, bm


def test_min_area_rule_drops_the_clusters_covering_less() -> None:
    angles = np.linspace(-1.1, 1.1, 512).astype(np.float32)
    ping, rb, bm = _two_targets(angles)
    kw: dict[str, Any] = dict(
        eps_m=0.25, min_samples=2, min_features=10, margin_m=0.2, min_side_m=0.5
    )
    both = extract_objects(ping, rb, bm, RANGES_M[rb], angles[bm], **kw)
    area = [
        cell_areas_m2(RANGES_M, angles, rb[both.feature_index[both.object_index == k]],
                      bm[both.feature_index[both.object_index == k]]).sum()
        for k in range(2)
    ]  # fmt: skip
    assert area[0] < 0.2 < area[1]
    big = extract_objects(ping, rb, bm, RANGES_M[rb], angles[bm], min_area_m2=0.2, **kw)
    assert big.count == 1
    np.testing.assert_array_equal(big.true_class_id, [2])
    np.testing.assert_array_equal(big.object_index, np.zeros(len(big.feature_index)))
    np.testing.assert_array_equal(big.feature_index, both.feature_index[both.object_index == 1])
    np.testing.assert_array_equal(big.patches[0], both.patches[1])
    none = extract_objects(ping, rb, bm, RANGES_M[rb], angles[bm], min_area_m2=1.0, **kw)
    assert none.count == 0 and none.patches.shape == (0, 40, 40)


def test_keep_clusters_renumbers_in_order() -> None:
    labels = np.array([2, -1, 0, 1, 2, 0, 3])
    np.testing.assert_array_equal(
        keep_clusters(labels, np.array([True, False, True, True])), [1, -1, 0, -1, 1, 0, 2]
    )


def test_fan_outside_area_counts_the_padded_box_beyond_the_fan() -> None:
    half = np.deg2rad(65.0)
    boxes = np.array(
        [
            [9.8, 10.2, -0.2, 0.2],  # centre: inside
            [-2.0, -1.0, 0.0, 1.0],  # behind the sonar: all 1 m2 outside
            [29.0, 29.9, -0.5, 0.5],  # padded to 30.15 m: beyond the 30 m arc
        ]
    )
    out = fan_outside_area_m2(boxes, 0.0, 30.0, -half, half)
    assert out[0] == 0.0
    assert out[1] == pytest.approx(1.0, rel=0.1)
    assert out[2] == 0.0
    padded = fan_outside_area_m2(boxes, 0.25, 30.0, -half, half)
    assert padded[0] == 0.0 and padded[2] > 0.1  # ~0.15 m x 1.5 m past the arc


def test_fan_edge_rule_drops_exactly_the_objects_cut_by_the_fan() -> None:
    angles, ranges = FAN_ANGLES, FAN_RANGES_M
    r, a = ranges[:, None].astype(np.float64), angles[None, :].astype(np.float64)
    x, y = r * np.cos(a), r * np.sin(a)

    def disc(rng: float, bearing_deg: float, radius: float) -> np.ndarray:
        cx, cy = rng * np.cos(np.deg2rad(bearing_deg)), rng * np.sin(np.deg2rad(bearing_deg))
        return np.hypot(x - cx, y - cy) <= radius

    # (range, bearing, radius, cut by the fan edge?)
    targets = [
        (10.0, 0.0, 0.3, False),
        (12.0, 55.0, 0.3, False),  # near the edge, its padded box still inside
        (8.0, 64.8, 0.3, True),  # straddles the +65 deg edge
        (15.0, -65.2, 0.4, True),  # straddles the -65 deg edge
        (30.05, -20.0, 0.3, True),  # straddles the 30 m arc
        (28.5, 20.0, 0.3, False),
    ]
    labels = np.zeros(x.shape, np.uint8)
    for n, (rng, bearing, radius, _) in enumerate(targets):
        labels[disc(rng, bearing, radius)] = n + 1
    image = np.where(labels > 0, 255, 0).astype(np.uint8)
    ping = SonarPing(0, "horizontal", image, ranges, angles, labels=labels)
    rb, bm = np.nonzero(labels)
    kw: dict[str, Any] = dict(
        eps_m=0.25, min_samples=2, min_features=10, margin_m=0.2, min_side_m=0.5
    )
    every = extract_objects(ping, rb, bm, ranges[rb], angles[bm], **kw)
    assert every.true_class_id is not None
    assert sorted(every.true_class_id.tolist()) == list(range(1, 7))
    kept = extract_objects(ping, rb, bm, ranges[rb], angles[bm], drop_fan_edge=True, **kw)
    want = [n + 1 for n, t in enumerate(targets) if not t[3]]
    assert kept.true_class_id is not None
    assert sorted(kept.true_class_id.tolist()) == want
    # Kept objects are unchanged (same features, boxes and patches), only renumbered.
    for k, cls in enumerate(kept.true_class_id):
        e = int(np.flatnonzero(every.true_class_id == cls)[0])
        np.testing.assert_array_equal(kept.boxes[k], every.boxes[e])
        np.testing.assert_array_equal(kept.patches[k], every.patches[e])
    # A tighter limit or margin changes what "reaches outside" means.
    lenient = extract_objects(
        ping, rb, bm, ranges[rb], angles[bm], drop_fan_edge=True, fan_edge_margin_m=0.0,
        fan_edge_max_outside_m2=10.0, **kw,
    )  # fmt: skip
    assert lenient.count == 6
