"""The "classify" stage: objects of every keyframe and their classes (paper Sec. IV.C).

Per keyframe: DBSCAN clusters of the horizontal sonar's features (metric fan-plane
coordinates), clusters of at least n features, 40x40 aspect-preserving patches; then
m Monte-Carlo dropout passes of the CNN over that keyframe's objects
(`sonarmap.stages.classify.cnn.mc_predict_groups`, one keyframe per call, so a keyframe's
result is the same whichever keyframes run beside it). Each keyframe's objects and beliefs
are a work unit the engine caches (`sonarmap.stages.classify.units`). Two cluster rules
of the authors' simulation code, off by default, drop objects before classification: a
minimum covered area (`min_object_area_m2`) and the fan edge (`drop_fan_edge_objects`);
see `sonarmap.stages.classify.objects`. An object takes the argmax class of the mean softmax when that
mean probability exceeds the threshold and is "unknown" otherwise; mean and variance
are recorded. Dropout masks are seeded per keyframe (seed, the keyframe's ping time) and
shared by its objects, so outputs are byte-identical run to run, and a keyframe keeps its
masks (and its work unit) at any keyframe spacing or position in the recording.

Beyond the paper (on by default, `pool_views`): the decision is taken on the class
distribution pooled over the sightings of the same place in nearby keyframes
(`sonarmap.stages.classify.view_pooling`, mapped with the dead-reckoning poses, since classify runs before
SLAM). A piling seen at 25 m, where its shape is hardly resolved, takes the class it shows
close up a few keyframes earlier or later. `probability` is then the pooled probability;
`single_view_probability` keeps this keyframe's own.

The patch geometry (margin, smallest side) and the clustering parameters come from the
model file, so objects are found and cut exactly as in training; the clustering fields of
this stage's config only override them.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.model_settings import ModelSettings
from sonarmap.schemas.objects import OBJECT_FEATURES_SCHEMA, OBJECTS_SCHEMA, UNKNOWN_CLASS_ID
from sonarmap.schemas.sensors import Sensors
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.base import UNITS_INPUT, Input, StageInputError, Units
from sonarmap.stages.classify import STAGE
from sonarmap.stages.classify.acceptance import acceptance_report
from sonarmap.stages.classify.class_columns import class_columns, truth_columns
from sonarmap.stages.classify.config import ClassifyConfig
from sonarmap.stages.classify.objects import KeyframeObjects, extract_objects, horizontal_features
from sonarmap.stages.classify.units import KeyframeResult, classify_base, keyframe_result
from sonarmap.stages.kernels.clustering import clustering
from sonarmap.stages.kernels.lazy import lazy

if TYPE_CHECKING:
    from sonarmap.stages.classify.cnn import PatchCNN

cnn = lazy("sonarmap.stages.classify.cnn")
view_pooling = lazy("sonarmap.stages.classify.view_pooling")  # scipy.spatial: only when pooling

__all__ = ["STAGE", "ClassifyConfig", "classify_keyframes", "clustering"]

log = logging.getLogger(__name__)


def keyframe_seed(seed: int, t_ns: int) -> int:
    """The dropout seed of the keyframe whose horizontal ping is at `t_ns`: 63 bits of the
    sha256 of (config seed, ping time), so it follows the ping, not the keyframe's id."""
    digest = hashlib.sha256(f"{int(seed)}:{int(t_ns)}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def _empty_features() -> dict[str, np.ndarray]:
    z_i, z_f = np.zeros(0, np.int64), np.zeros(0, np.float64)
    return {"feature_id": z_i, "range_bin": z_i, "beam": z_i, "range_m": z_f, "angle_rad": z_f}


_CLASS_COLUMNS = (
    "class_id", "class_name", "argmax_class_name", "probability", "probability_var",
    "single_view_probability", "n_views",
)  # fmt: skip
_GEOMETRY_SCHEMA = pa.schema([f for f in OBJECTS_SCHEMA if f.name not in _CLASS_COLUMNS])


def _object_rows(
    frame: KeyframeImages, objs: KeyframeResult, first_id: int, table: ClassTable
) -> dict[str, Any]:
    """The class-independent columns of objects.parquet for one keyframe's k objects."""
    k = objs.count
    truth = objs.true_class_id
    cx, cy = objs.centroid_xy[:, 0], objs.centroid_xy[:, 1]
    return {
        "keyframe_id": np.full(k, frame.keyframe_id, np.int64),
        "object_id": np.arange(first_id, first_id + k, dtype=np.int64),
        "n_features": objs.n_features,
        "x_m": cx, "y_m": cy, "range_m": np.hypot(cx, cy), "bearing_rad": np.arctan2(cy, cx),
        "x_min_m": objs.boxes[:, 0], "x_max_m": objs.boxes[:, 1],
        "y_min_m": objs.boxes[:, 2], "y_max_m": objs.boxes[:, 3],
        "true_class_name": [table.name_of(int(c)) for c in truth] if truth is not None else [None] * k,
    }  # fmt: skip


def _pooled(
    mean: np.ndarray, geometry: pa.Table, keyframes: pa.Table, T_base_sonar: np.ndarray,
    cfg: ClassifyConfig, fans: Mapping[int, tuple[float, float, float, float]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:  # fmt: skip
    """Each object's class distribution pooled over its sightings, how many sightings
    pooled, and the share of the keyframes whose fan covered its place that sighted it
    (None when `min_seen_share` is off; `sonarmap.stages.classify.view_pooling`)."""
    keyframes = keyframes.sort_by("keyframe_id")
    kf_ids = keyframes.column("keyframe_id").to_numpy().astype(np.int64)
    cols = [keyframes.column(c) for c in ("x_m", "y_m", "yaw_rad")]
    if any(c.null_count for c in cols):
        why = "x_m, y_m or yaw_rad has nulls; set classify.pool_views=false"
        raise StageInputError(Input("keyframes", "keyframes"), why)
    pose = np.column_stack([c.to_numpy() for c in cols]).astype(np.float64)
    obj_kf = geometry.column("keyframe_id").to_numpy()
    row = np.searchsorted(kf_ids, obj_kf)
    if len(obj_kf) and (row.max() >= len(kf_ids) or (kf_ids[row] != obj_kf).any()):
        raise ValueError("keyframes: an object's keyframe_id is not in keyframes.parquet")
    xy = np.column_stack([geometry.column("x_m").to_numpy(), geometry.column("y_m").to_numpy()])
    world = view_pooling.sighting_world_xy(xy, pose[row], T_base_sonar)
    along = view_pooling.along_track_m(pose[:, :2])
    pooled, n_views = view_pooling.pool_views(
        mean, world, obj_kf, along[row], geometry.column("range_m").to_numpy(),
        radius_m=cfg.pool_radius_m, window_m=cfg.pool_window_m,
        range_scale_m=cfg.pool_range_scale_m,
    )  # fmt: skip
    if cfg.min_seen_share <= 0:  # the rule is off: no coverage to count
        return pooled, n_views, None
    # The horizontal sonar's world pose at each keyframe with an image, and its fan.
    imaged = np.isin(kf_ids, np.fromiter(fans, np.int64, len(fans)))
    origin = view_pooling.sighting_world_xy(np.zeros((imaged.sum(), 2)), pose[imaged], T_base_sonar)
    heading = pose[imaged, 2] + np.arctan2(T_base_sonar[1, 0], T_base_sonar[0, 0])
    cover = view_pooling.fan_coverage(
        world, along[row], np.column_stack([origin, heading]),
        np.array([fans[int(k)] for k in kf_ids[imaged]]).reshape(-1, 4), along[imaged],
        cfg.pool_window_m, margin_m=cfg.pool_radius_m,
    )  # fmt: skip
    return pooled, n_views, n_views / np.maximum(cover, 1)


def classify_keyframes(
    frames: Sequence[KeyframeImages],
    features: pa.Table,
    model: Callable[[], PatchCNN],
    class_names: list[str],
    settings: ModelSettings,
    cfg: ClassifyConfig,
    keyframes: pa.Table | None = None,
    T_base_sonar: np.ndarray | None = None,
    table: ClassTable = DEFAULT_TABLE,
    units: Units | None = None,
    base: Mapping[str, Any] | None = None,
) -> tuple[pa.Table, pa.Table, np.ndarray | None]:
    """Objects and classes of every keyframe.

    Args:
        frames: keyframe images in keyframe order (read one at a time).
        features: features.parquet (only horizontal rows are used).
        model: gives the classifier (called only for a keyframe not in `units`);
            class_names: its output names; settings: the model file's clustering and
            patch settings.
        cfg: clustering, acceptance and pooling config.
        keyframes: keyframes.parquet (dead-reckoning poses) and T_base_sonar: (4, 4)
            mounting of the horizontal sonar; both needed when `cfg.pool_views`.
        table: the class table (config section `classes`): label ids of the model's
            classes and names of label-image ids.
        units, base: the engine's per-keyframe memo and what every unit key shares
            (`sonarmap.stages.classify.units`); None: every keyframe computed.

    Returns:
        (objects table, object_features table, each object's largest single-view class
        probability: None with labels from ground truth).
    """
    if cfg.pool_views and (keyframes is None or T_base_sonar is None):
        raise ValueError("classify.pool_views needs the keyframes' poses and the sonar mounting")
    by_kf = horizontal_features(features)
    eps_m, min_samples, min_features = clustering(cfg, settings).values()
    table.check(class_names, "the classifier's classes", unknown_ok=False)
    base = base if base is not None else {}
    class_ids = np.array([table.ids[n] for n in class_names], np.int64)
    geo_parts: list[pa.Table] = []
    link_parts: list[pa.Table] = []
    truths: list[np.ndarray] = [np.zeros(0, np.int64)]
    beliefs: list[tuple[np.ndarray, np.ndarray]] = []
    oracle = cfg.labels == "ground_truth"

    def extract(frame: KeyframeImages, f: dict[str, np.ndarray]) -> KeyframeObjects:
        return extract_objects(
            frame.horizontal, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
            eps_m=eps_m, min_samples=min_samples, min_features=min_features,
            margin_m=settings.margin_m, min_side_m=settings.min_side_m,
            size_px=settings.size_px, min_area_m2=cfg.min_object_area_m2,
            drop_fan_edge=cfg.drop_fan_edge_objects, fan_edge_margin_m=cfg.fan_edge_margin_m,
            fan_edge_max_outside_m2=cfg.fan_edge_max_outside_m2,
            normalisation=settings.patch_normalisation,
        )  # fmt: skip

    next_id = 0
    fans: dict[int, tuple[float, float, float, float]] = {}  # the image each keyframe covers
    for frame in frames:
        h = frame.horizontal
        fans[frame.keyframe_id] = (
            float(h.ranges_m[0]), float(h.ranges_m[-1]),
            float(h.angles_rad[0]), float(h.angles_rad[-1]),
        )  # fmt: skip
        f = by_kf.get(frame.keyframe_id) or _empty_features()
        seed = keyframe_seed(cfg.seed, frame.t_ns)
        objs = keyframe_result(
            frame, f, extract, model, len(class_names), settings, cfg, seed, base, units
        )
        if oracle:
            if objs.true_class_id is None:
                raise StageInputError(
                    Input("keyframes", "frames"),
                    f"classify.labels=ground_truth: keyframe {frame.keyframe_id} has no label"
                    " image (a field recording?); use classify.labels=cnn",
                )
            truths.append(objs.true_class_id.astype(np.int64))
        else:
            beliefs.append((objs.mean, objs.var))
        geo_parts.append(
            pa.Table.from_pydict(_object_rows(frame, objs, next_id, table), schema=_GEOMETRY_SCHEMA)
        )
        link_parts.append(
            pa.Table.from_pydict(
                {
                    "keyframe_id": np.full(len(objs.feature_index), frame.keyframe_id, np.int64),
                    "object_id": next_id + objs.object_index,
                    "feature_id": f["feature_id"][objs.feature_index].astype(np.int64),
                },
                schema=OBJECT_FEATURES_SCHEMA,
            ).sort_by([("object_id", "ascending"), ("feature_id", "ascending")])
        )
        next_id += objs.count
    if not geo_parts or next_id == 0:
        empty = None if oracle else np.zeros(0)
        return OBJECTS_SCHEMA.empty_table(), OBJECT_FEATURES_SCHEMA.empty_table(), empty
    geometry = pa.concat_tables([t for t in geo_parts if t.num_rows])
    single_view_max = None
    if oracle:
        classes = truth_columns(np.concatenate(truths), class_names, table)
    else:
        mean = np.concatenate([m for m, _ in beliefs])
        var = np.concatenate([v for _, v in beliefs])
        single_view_max = mean.max(axis=1) if len(mean) else np.zeros(0)
        seen, min_views = None, 1  # without pooling, no sighting is matched to another
        if cfg.pool_views:
            assert keyframes is not None and T_base_sonar is not None
            pooled, n_views, seen = _pooled(mean, geometry, keyframes, T_base_sonar, cfg, fans)
            min_views = cfg.min_views
        else:
            pooled, n_views = mean, np.ones(len(mean), np.int64)
        compact = np.array([table.entry(n).frame_kind == "object" for n in class_names])
        classes = class_columns(
            pooled, mean, var, n_views, class_ids, class_names, cfg.threshold, min_views,
            seen, cfg.min_seen_share, compact,
        )  # fmt: skip
    columns = {name: geometry.column(name) for name in geometry.column_names}
    objects = pa.Table.from_pydict(
        {f.name: columns.get(f.name, classes.get(f.name)) for f in OBJECTS_SCHEMA},
        schema=OBJECTS_SCHEMA,
    )
    links = pa.concat_tables(link_parts)
    log.info("classified %d objects in %d keyframes", objects.num_rows, len(geo_parts))
    return objects, links, single_view_max


class LazyModel:
    """The CNN of a model file, loaded on the first call (torch imported, its threads
    fixed to one until `close`): a run whose every keyframe is a cached unit loads none.

    The class names and settings come from the model's `settings.json` where it has one
    (train version 8 on), else from the model file, loaded at once. A model file that
    disagrees with its `settings.json` is refused when it is loaded.
    """

    def __init__(self, data: bytes, settings: Any) -> None:
        self.data = data
        self._net: PatchCNN | None = None
        self._threads = contextlib.ExitStack()
        ok = isinstance(settings, Mapping) and isinstance(settings.get("config"), Mapping)
        if ok and isinstance(settings.get("class_names"), list):
            self.names = [str(n) for n in settings["class_names"]]
            self.config = dict(settings["config"])
        else:
            self.names, self.config = [], {}
            try:
                self()  # no settings.json: the model file says
            except BaseException:
                self.close()  # the thread count is restored whatever the model file held
                raise

    def __call__(self) -> PatchCNN:
        if self._net is not None:
            return self._net
        self._threads.enter_context(cnn.fixed_threads(1))
        try:
            net, names, config = cnn.model_from_bytes(self.data)
        except ValueError as err:
            raise StageInputError(Input("train", "model"), str(err)) from err
        if self.names and (names, _as_json(config)) != (self.names, _as_json(self.config)):
            why = "the model file's classes or settings differ from its settings.json"
            raise StageInputError(Input("train", "model"), why)
        self._net, self.names, self.config = net, names, config
        return net

    def close(self) -> None:
        self._threads.close()


def _as_json(value: Any) -> Any:
    return json.loads(json.dumps(value))


def _run(config: ClassifyConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    model_bytes = inputs["train.model"]
    if not isinstance(model_bytes, bytes | bytearray):
        raise ValueError(f"train.model must be bytes, got {type(model_bytes).__name__}")
    model = LazyModel(bytes(model_bytes), inputs.get("train.settings"))
    try:
        return _classify(config, inputs, model)
    finally:
        model.close()


def _classify(
    config: ClassifyConfig, inputs: Mapping[str, Any], model: LazyModel
) -> dict[str, Any]:
    model_bytes, names, mcfg = model.data, model.names, model.config
    try:
        settings = ModelSettings.from_config(mcfg)
        params = clustering(config, settings)
    except (ValueError, KeyError, TypeError) as err:
        raise StageInputError(Input("train", "settings"), f"model settings: {err}") from err
    keyframes, sensors = inputs.get("keyframes.keyframes"), inputs.get("keyframes.sensors")
    mount = None if sensors is None else Sensors.of(sensors).horizontal.T_base_sonar
    table: ClassTable = inputs.get("config.classes", DEFAULT_TABLE)
    try:
        table.check(names, "train.model: the classifier's classes", unknown_ok=False)
    except ValueError as err:
        raise StageInputError(Input("train", "model"), str(err)) from err
    units = inputs.get(UNITS_INPUT)
    base = classify_base(
        STAGE.name, STAGE.version, config, STAGE.key_excludes, model_bytes, table,
        _as_json({"class_names": names, "config": mcfg}),
    )  # fmt: skip
    objects, links, single_view_max = classify_keyframes(
        inputs["keyframes.frames"], inputs["features.features"], model, names, settings, config,
        keyframes, mount, table, units, base,
    )  # fmt: skip
    # The view-agreement check compares confidence alone, pooled against single views;
    # the sure objects the `min_views` and `min_seen_share` rules hold back beside it.
    accepted = int(np.sum(objects.column("class_id").to_numpy() != UNKNOWN_CLASS_ID))
    sure = int(np.sum(objects.column("probability").to_numpy() > config.threshold))
    acceptance = acceptance_report(
        single_view_max, sure, inputs.get("train.metrics"), config.threshold
    )
    unknown = [e.name for e in table.table if e.inferred and e.name not in names]
    if unknown:  # a class added to the table, its labels never reached the model
        acceptance["warnings"].append(
            f"classify: the model has no class {', '.join(unknown)} (inferred in"
            " classes.table): no object gets it, so it is never inferred; train a model on"
            " labels of it (docs/labels-and-classes.md)"
        )
    if single_view_max is not None:
        acceptance["unconfirmed"] = sure - accepted
        acceptance["min_views"] = config.min_views if config.pool_views else 1
        acceptance["min_seen_share"] = config.min_seen_share if config.pool_views else 0.0
    return {
        "objects": objects, "object_features": links, "clustering": params,
        "acceptance": acceptance,
    }  # fmt: skip
