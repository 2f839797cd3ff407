"""The "train" stage: fit the object classifier on labelled keyframes (paper Sec. IV.C).

Samples are the objects the classify stage itself would see: DBSCAN clusters of
horizontal features (CFAR features when given, else the label image's labelled cells),
each cropped to a 40x40 aspect-preserving patch; the label is the majority
label-image class of the cluster's cells (simulator labels give classes for free).

Training follows the paper: augmentation with Gaussian noise, random flips and random
rotations; classes balanced by sampling each epoch uniformly over classes; Adam with a
one-cycle learning-rate schedule; fixed seeds.
Validation holds out whole blocks of consecutive keyframes with a guard gap, so the same
view of an object never lands on both sides (with several datasets, the last one is
the validation set when `split` is "dataset", which also keeps objects apart); given
held-out datasets (whole worlds), they validate and `size_rule` picks the set's size.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import KeyframeImages
from sonarmap.stages.classify.objects import PATCH_SIZE_PX, extract_objects, horizontal_features
from sonarmap.stages.classify.sensor_noise import noisy_image
from sonarmap.stages.classify.size_rule import curve_png, grow, one_size
from sonarmap.stages.classify.train_config import TrainConfig
from sonarmap.stages.classify.training import STAGE
from sonarmap.stages.classify.validation import confusion_png, evaluate, say_what_is_not_learned
from sonarmap.stages.kernels.lazy import lazy

if TYPE_CHECKING:
    from sonarmap.stages.classify.cnn import PatchCNN

torch = lazy("torch")
F = lazy("torch.nn.functional")
cnn = lazy("sonarmap.stages.classify.cnn")

__all__ = [
    "STAGE",
    "Samples",
    "TrainConfig",
    "augment",
    "collect_samples",
    "features_from_labels",
    "fit",
    "split_train_val",
    "train_classifier",
]

log = logging.getLogger(__name__)

NO_STRUCTURE = 0
"""The class id of objects on no labelled structure ("none"): learned only when validation
holds some of them (`_train_classifier`)."""


@dataclass(frozen=True)
class Samples:
    """Training samples: patches (n, 40, 40) float32, class ids (n,) int64 (label-image
    ids), keyframe ids (n,) int64, dataset index (n,) int64."""

    patches: np.ndarray
    class_id: np.ndarray
    keyframe_id: np.ndarray
    dataset: np.ndarray


def features_from_labels(frame: KeyframeImages) -> dict[str, np.ndarray]:
    """Stand-in features of a labelled keyframe: every horizontal cell with a label > 0.

    Returns:
        {feature_id, range_bin, beam, range_m, angle_rad}: (n,) arrays, row-major order.
    """
    ping = frame.horizontal
    if ping.labels is None:
        raise ValueError(f"keyframe {frame.keyframe_id} has no label image")
    rb, bm = np.nonzero(ping.labels > 0)
    return {
        "feature_id": np.arange(len(rb), dtype=np.int64),
        "range_bin": rb.astype(np.int64),
        "beam": bm.astype(np.int64),
        "range_m": ping.ranges_m[rb].astype(np.float64),
        "angle_rad": ping.angles_rad[bm].astype(np.float64),
    }


def collect_samples(
    datasets: Sequence[tuple[Iterable[KeyframeImages], pa.Table | None]], cfg: TrainConfig
) -> Samples:
    """Objects of labelled keyframes -> patches and majority classes.

    Args:
        datasets: (keyframes, features table or None) per dataset; None uses
            `features_from_labels`.
        cfg: clustering and crop parameters.

    Raises:
        ValueError: a keyframe without a label image.
    """
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for d, (frames, table) in enumerate(datasets):
        by_kf = horizontal_features(table) if table is not None else None
        for frame in frames:
            if frame.horizontal.labels is None:
                raise ValueError(f"keyframe {frame.keyframe_id} has no label image")
            if by_kf is None:
                f = features_from_labels(frame)
            elif frame.keyframe_id in by_kf:
                f = by_kf[frame.keyframe_id]
            else:
                continue
            ping = frame.horizontal
            for copy in range(1 + cfg.sensor_copies):
                if copy:  # the same objects seen through another sensor's noise floor
                    seed = (cfg.seed, d, frame.keyframe_id, copy)
                    image = noisy_image(
                        frame.horizontal.image, cfg.sensor_noise_mean_level,
                        cfg.sensor_noise_shape, seed,
                    )  # fmt: skip
                    ping = replace(frame.horizontal, image=image)
                objs = extract_objects(
                    ping, f["range_bin"], f["beam"], f["range_m"], f["angle_rad"],
                    eps_m=cfg.eps_m, min_samples=cfg.min_samples, min_features=cfg.min_features,
                    margin_m=cfg.margin_m, min_side_m=cfg.min_side_m,
                    normalisation=cfg.patch_normalisation,
                )  # fmt: skip
                assert objs.true_class_id is not None
                k = objs.count
                kf, ds = np.full(k, frame.keyframe_id, np.int64), np.full(k, d, np.int64)
                parts.append((objs.patches, objs.true_class_id, kf, ds))
    if not parts:
        z = np.zeros(0, np.int64)
        return Samples(np.zeros((0, PATCH_SIZE_PX, PATCH_SIZE_PX), np.float32), z, z, z)
    cols = [np.concatenate(c) for c in zip(*parts, strict=True)]
    return Samples(*cols)


def split_train_val(samples: Samples, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (train, val) masks: blocks of keyframes (or the last dataset) validate.

    With split="keyframes", block b = keyframe_id // val_block_keyframes of each dataset
    validates when b % val_every_blocks == val_every_blocks - 1; training keyframes within
    `guard_keyframes` of a validation block are used by neither side.
    """
    if cfg.split == "dataset" and samples.dataset.max(initial=0) > 0:
        val = samples.dataset == samples.dataset.max()
        return ~val, val
    kf = samples.keyframe_id
    block = kf // cfg.val_block_keyframes
    val = block % cfg.val_every_blocks == cfg.val_every_blocks - 1
    pos = kf % cfg.val_block_keyframes
    near_next = (block % cfg.val_every_blocks == cfg.val_every_blocks - 2) & (
        pos >= cfg.val_block_keyframes - cfg.guard_keyframes
    )
    near_prev = (block % cfg.val_every_blocks == 0) & (block > 0) & (pos < cfg.guard_keyframes)
    return ~val & ~near_next & ~near_prev, val


def augment(x: torch.Tensor, cfg: TrainConfig, gen: torch.Generator) -> torch.Tensor:
    """Paper's augmentation on a batch: random flips, random rotations, Gaussian noise.

    Patches are cut in the line-of-sight frame, so the default flips mirror left-right
    only and rotations are small (an object's own yaw); near/far flips are optional.
    Rotations default to +-5 deg and noise to none, because rotating a sonar patch is not
    rotating the object and noise buries faint returns; both stay available
    (docs/decisions/012-small-rotations-no-noise.md).

    Args:
        x: (n, 1, s, s) patches in [0, 1].

    Returns:
        (n, 1, s, s) augmented patches clipped to [0, 1].
    """
    n = x.shape[0]
    sx = torch.ones(n)
    sy = torch.ones(n)
    if cfg.flips:
        sx = torch.where(torch.rand(n, generator=gen) < 0.5, -1.0, 1.0)
    if cfg.flip_near_far:
        sy = torch.where(torch.rand(n, generator=gen) < 0.5, -1.0, 1.0)
    ang = (torch.rand(n, generator=gen) * 2 - 1) * np.deg2rad(cfg.max_rotation_deg)
    c, s = torch.cos(ang), torch.sin(ang)
    theta = torch.stack(
        [torch.stack([c * sx, -s * sy, torch.zeros(n)], 1), torch.stack([s * sx, c * sy, torch.zeros(n)], 1)],
        1,
    )  # fmt: skip
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    out = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    out = out + cfg.noise_std * torch.randn(out.shape, generator=gen)
    return out.clamp_(0.0, 1.0)


def epochs_for(n_samples: int, cfg: TrainConfig) -> int:
    """`cfg.epochs`, cut so that n_samples x epochs stays within `cfg.max_presentations`."""
    return max(1, min(cfg.epochs, cfg.max_presentations // max(n_samples, 1)))


def fit(patches: np.ndarray, target: np.ndarray, n_classes: int, cfg: TrainConfig) -> PatchCNN:
    """Train a `PatchCNN` with Adam on class-balanced, augmented epochs.

    Args:
        patches: (n, s, s) float32 in [0, 1].
        target: (n,) int64 model class indices 0..n_classes-1.
        n_classes: number of outputs.
        cfg: hyper-parameters and seed.

    Returns:
        The trained model in eval mode (its dropout stays active: MC dropout).
    """
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    model = cnn.PatchCNN(
        n_classes, cfg.channels, cfg.hidden, cfg.dropout_p, PATCH_SIZE_PX, cfg.spatial_dropout
    )
    opt = torch.optim.Adam(model.parameters(), lr=cfg.learning_rate, eps=1e-7)
    epochs = epochs_for(len(target), cfg)
    steps = epochs * -(-len(target) // cfg.batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.learning_rate, total_steps=max(steps, 1))
    x_all = torch.from_numpy(np.ascontiguousarray(patches, np.float32))[:, None]
    y_all = torch.from_numpy(target.astype(np.int64))
    counts = torch.bincount(y_all, minlength=n_classes).double()
    weights = (1.0 / counts.clamp(min=1))[y_all]
    n = len(y_all)
    model.train()
    for epoch in range(epochs):
        idx = torch.multinomial(weights, n, replacement=True, generator=gen)
        total = 0.0
        for start in range(0, n, cfg.batch_size):
            b = idx[start : start + cfg.batch_size]
            xb = augment(x_all[b], cfg, gen)
            loss = F.cross_entropy(model(xb, generator=gen), y_all[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(b)
        log.debug("epoch %d loss %.4f", epoch, total / max(n, 1))
    return model.eval()


def _learned_classes(class_id: np.ndarray, min_samples: int, n_ids: int) -> list[int]:
    counts = np.bincount(class_id, minlength=n_ids)
    return [int(c) for c in np.flatnonzero(counts >= min_samples)]


class TooFewLabels(ValueError):
    """The labelled objects hold fewer than two classes with enough training objects:
    bad input (more labels are needed), not a bug."""


class UnknownLabel(ValueError):
    """A dataset's labels hold a class id the class table lacks (a class left out of the
    config's `classes`): bad input, naming the dataset (`dataset`: its index)."""

    def __init__(self, label_id: int, dataset: int) -> None:
        super().__init__(
            f"its labels hold class id {label_id}, which the class table (config section"
            " `classes`) does not name: add the class back, or relabel those objects"
        )
        self.label_id, self.dataset = label_id, dataset


def train_classifier(
    datasets: Sequence[tuple[Iterable[KeyframeImages], pa.Table | None]],
    cfg: TrainConfig,
    table: ClassTable = DEFAULT_TABLE,
    heldout: Sequence[tuple[Iterable[KeyframeImages], pa.Table | None]] = (),
) -> dict[str, Any]:
    """Samples -> split -> fit -> validation metrics -> model file.

    Args:
        datasets: (labelled keyframes, features table or None) per dataset.
        cfg: training config.
        table: the class table (config section `classes`): names of the label ids; the
            model's outputs are the table's classes with enough training objects.
        heldout: datasets that only validate (whole worlds held out); with them, the
            training set's size is chosen by `sonarmap.stages.classify.size_rule`.

    Returns:
        {"model": bytes (model.pt), "metrics": dict, "confusion": bytes (PNG), "curve":
        bytes (PNG, held-out macro-F1 against the training-set size; one point without
        held-out datasets)}.

    Raises:
        ValueError: fewer than two classes with `min_class_samples` training samples.
    """
    with cnn.fixed_threads(2):
        return _train_classifier(datasets, cfg, table, heldout)


def _train_classifier(
    datasets: Sequence[tuple[Iterable[KeyframeImages], pa.Table | None]],
    cfg: TrainConfig,
    table: ClassTable,
    heldout: Sequence[tuple[Iterable[KeyframeImages], pa.Table | None]],
) -> dict[str, Any]:
    samples = collect_samples([*datasets, *heldout], cfg)
    n_ids = max(len(table.names_by_id()), int(samples.class_id.max(initial=0)) + 1)
    outside = sorted(set(np.unique(samples.class_id).tolist()) - set(table.ids.values()))
    if outside:
        first = int(samples.dataset[samples.class_id == outside[0]].min())
        raise UnknownLabel(outside[0], first)
    if heldout:
        val = samples.dataset >= len(datasets)
        train = ~val
    else:
        train, val = split_train_val(samples, cfg)
    ids = _learned_classes(samples.class_id[train], cfg.min_class_samples, n_ids)
    said: list[str] = []  # the training's warnings, kept in metrics.json
    if NO_STRUCTURE in ids and not (samples.class_id[val] == NO_STRUCTURE).any():
        # Id 0 labels clusters on no structure: a reject class. Learned from a handful of
        # stray clusters that validation cannot measure, it draws probability from the
        # structure classes everywhere (the shipped model with 12 of them: validation
        # accuracy 0.781 against 0.784 without, accepted share 0.53 against 0.61).
        ids.remove(NO_STRUCTURE)
        said.append(
            f"class {table.name_of(NO_STRUCTURE)}: "
            f"{int((samples.class_id[train] == NO_STRUCTURE).sum())} training objects and none"
            " held out for validation: not learned"
        )
        log.warning("%s", said[-1])
    said += say_what_is_not_learned(samples.class_id, train, val, ids, cfg.min_class_samples, table)
    if len(ids) < 2:
        raise TooFewLabels(
            f"need two classes with >= {cfg.min_class_samples} training objects, "
            f"have {np.bincount(samples.class_id[train], minlength=n_ids).tolist()}"
        )
    lut = np.full(n_ids, -1, np.int64)
    lut[ids] = np.arange(len(ids))
    names = [table.name_of(i) for i in ids]
    target = lut[samples.class_id]
    train &= target >= 0
    val &= target >= 0

    def fit_on(mask: np.ndarray) -> PatchCNN:
        return fit(samples.patches[mask], target[mask], len(ids), cfg)

    def score(model: PatchCNN) -> dict[str, Any]:
        return evaluate(model, samples.patches[val], target[val], names, cfg)

    if heldout:
        model, curve = grow(samples.dataset, train, len(datasets), fit_on, score, cfg)
        train &= samples.dataset < curve["chosen_datasets"]
        metrics = score(model)
    else:
        model = fit_on(train)
        metrics = score(model)
        curve = one_size(len(datasets), int(train.sum()), metrics["confusion"])
    metrics["size_rule"] = curve
    metrics["warnings"] = said  # replayed from the manifest when the model is reused
    metrics["n_train"] = int(train.sum())
    metrics["train_support"] = {
        n: int(c)
        for n, c in zip(names, np.bincount(target[train], minlength=len(ids)), strict=True)
    }
    model_cfg = {
        "channels": list(cfg.channels), "hidden": cfg.hidden, "dropout_p": cfg.dropout_p,
        "size_px": PATCH_SIZE_PX, "spatial_dropout": cfg.spatial_dropout, "margin_m": cfg.margin_m, "min_side_m": cfg.min_side_m,
        "eps_m": cfg.eps_m, "min_samples": cfg.min_samples, "min_features": cfg.min_features,
        "patch_normalisation": cfg.patch_normalisation,
        "class_ids": [table.ids[n] for n in names],
    }  # fmt: skip
    return {
        "model": cnn.model_to_bytes(model, names, model_cfg),
        # What classify needs of the model before (or without) running it, readable
        # without torch: a run whose every keyframe is a cached unit never loads the CNN.
        "settings": {"class_names": names, "config": model_cfg},
        "metrics": metrics,
        "confusion": confusion_png(metrics["confusion"], names),
        "curve": curve_png(curve),
    }


def _run(config: TrainConfig, inputs: Mapping[str, Any]) -> dict[str, Any]:
    pairs = [(inputs["keyframes.frames"], inputs["features.features"])]
    return train_classifier(pairs, config, inputs.get("config.classes", DEFAULT_TABLE))
