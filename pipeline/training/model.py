"""The default classifier: trained on simulated scenes other than the one being mapped.

Training is an ordinary cached stage. Each training dataset goes through the graph up
to `features` (cached per dataset like any run); the `train` stage then reads all of
them, so its key covers every dataset's keyframes and features, the train config, and
the stage version. The training datasets are built with the `training` section's own
`keyframes` and `features` settings, so a run's `--set keyframes.spacing_m=4` maps
with the same model (`training.follow_run: true` builds them with the run's settings
instead). `sonarmap run` binds the resulting `model.pt` to `classify`'s "train.model"
input; trained models live in the machine-wide cache of `sonarmap.pipeline.training.model_cache` (`resolve_model`).

A recording with an annotation file beside it (`<stem>.annotations.yaml`, format in
`sonarmap.schemas.annotations`) is labelled by that file instead of label images: its content
becomes an "annotations" artifact that `train` also reads, so editing it retrains.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sonarmap.schemas.sonar import KeyframeImages

from pydantic import BaseModel

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.run.graph import Graph
from sonarmap.pipeline.engine.run.planned import DatasetSpec
from sonarmap.pipeline.engine.run.planner import plan
from sonarmap.pipeline.engine.run.runner import execute
from sonarmap.pipeline.engine.run.session import dataset_spec
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore
from sonarmap.pipeline.training.config import TrainingDataConfig
from sonarmap.pipeline.training.datasets import Simulation
from sonarmap.schemas.classes import DEFAULT_TABLE
from sonarmap.stages.base import Input, Stage

__all__ = [
    "dataset_fingerprints",
    "ordered_datasets",
    "plan_training",
    "recorded_datasets",
    "train_on",
    "training_config",
    "training_datasets",
    "training_simulations",
    "training_stage_for",
]

log = logging.getLogger(__name__)


def training_config(config: BaseModel) -> BaseModel:
    """`config` with the `keyframes`/`features` sections the training datasets are built with.

    Those of the `training` section unless `training.follow_run`; the run's own otherwise.
    """
    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    if training.follow_run:
        return config
    sections = {"keyframes": training.keyframes, "features": training.features}
    fields = type(config).model_fields
    return config.model_copy(update={k: v for k, v in sections.items() if k in fields})


def _unmatched_is_bad_input(frames: Iterator[KeyframeImages]) -> Iterator[KeyframeImages]:
    """`frames`, with annotations matching no keyframe raised as a SourceError (exit 2)."""
    from sonarmap.stages.classify.annotations import UnmatchedAnnotations

    try:
        yield from frames
    except UnmatchedAnnotations as err:
        raise SourceError(str(err)) from err


def _prefix(i: int, n_datasets: int, heldout: int) -> str:
    """Input-name prefix of dataset i: "val_" for the last `heldout` (so a dataset's role
    is in the train key), "" otherwise."""
    return "val_" if i >= n_datasets - heldout else ""


def training_stage_for(
    n_datasets: int, annotated: Sequence[int] = (), names: Sequence[str] = (), heldout: int = 0
) -> Stage:
    """The `train` stage reading `n_datasets` (keyframes, features) pairs.

    Inputs are bound as "keyframes_i.frames" / "features_i.features" so one stage run
    sees every dataset; dataset i in `annotated` also reads "annotations_i.annotations"
    and is labelled by it (`sonarmap.stages.classify.annotations.label_keyframes`) instead of label
    images. The last `heldout` datasets (inputs "val_keyframes_i" ...) only validate:
    whole worlds held out, and the size rule of `sonarmap.stages.classify.train` grows the
    training set over the others. `names` (the datasets' paths) only word error
    messages. Outputs and config are those of `sonarmap.stages.classify.train`.
    """
    from sonarmap.pipeline.engine.text import one_line
    from sonarmap.pipeline.training.annotations import annotation_path
    from sonarmap.schemas.annotations import AnnotationFile
    from sonarmap.stages.classify.training import STAGE as base

    pre = [_prefix(i, n_datasets, heldout) for i in range(n_datasets)]
    inputs = tuple(
        item
        for i in range(n_datasets)
        for item in (
            Input(f"{pre[i]}keyframes_{i}", "frames"),
            Input(f"{pre[i]}features_{i}", "features"),
            *([Input(f"{pre[i]}annotations_{i}", "annotations")] if i in annotated else []),
        )
    )

    def name(i: int) -> str:
        return names[i] if i < len(names) else f"dataset {i}"

    def labelled(i: int, frames: Iterable[KeyframeImages]) -> Iterator[KeyframeImages]:
        for frame in frames:
            if frame.horizontal.labels is None:
                stem = Path(name(i)).stem
                raise ValueError(
                    f"{name(i)}: keyframe {frame.keyframe_id} has no label image "
                    f"(a field recording needs {stem}.annotations.yaml beside it)"
                )
            yield frame

    def frames(i: int, bound: Mapping[str, Any]) -> Iterable[KeyframeImages]:
        kf = bound[f"{pre[i]}keyframes_{i}.frames"]
        if i not in annotated:
            return labelled(i, kf)
        table = bound.get("config.classes", DEFAULT_TABLE)
        doc = AnnotationFile.model_validate(
            bound[f"{pre[i]}annotations_{i}.annotations"], context={"classes": table}
        )
        ann = annotation_path(Path(name(i))) if i < len(names) else None
        source = one_line(str(ann)) if ann is not None else f"annotations of {name(i)}"
        features = bound[f"{pre[i]}features_{i}.features"]
        from sonarmap.stages.classify.annotations import label_keyframes

        return _unmatched_is_bad_input(
            label_keyframes(kf, doc, source=source, features=features, table=table)
        )

    def run(config: Any, bound: Mapping[str, Any]) -> Mapping[str, Any]:
        from sonarmap.pipeline.engine.errors import ConfigError
        from sonarmap.stages.classify.train import TooFewLabels, UnknownLabel, train_classifier

        pairs = [
            (frames(i, bound), bound[f"{pre[i]}features_{i}.features"]) for i in range(n_datasets)
        ]
        n_train = n_datasets - heldout
        table = bound.get("config.classes", DEFAULT_TABLE)
        try:
            return train_classifier(pairs[:n_train], config, table, heldout=pairs[n_train:])
        except UnknownLabel as err:  # the user's labels or classes, not a bug: exit 2
            raise ConfigError(f"train: {name(err.dataset)}: {err}") from None
        except TooFewLabels as err:  # the user's labels, not a bug: exit 2
            raise ConfigError(
                f"train: {err} (by class id); label more objects, of at least two classes"
                " (docs/labels-and-classes.md)"
            ) from None

    return Stage(
        base.name, base.version, base.config, inputs, base.outputs, run, base.description,
        reads_sections=base.reads_sections,
    )  # fmt: skip


def _bind_training(
    datasets: Sequence[Path],
    config: BaseModel,
    store: ArtifactStore,
    *,
    compute: bool,
    fingerprints: Mapping[Path, str] | None = None,
    heldout: int = 0,
) -> tuple[Stage, dict[str, tuple[Stage, ArtifactRef]], DatasetSpec]:
    """The train stage and its bound inputs: computed artifacts, or key-only placeholders.

    With `compute=False` nothing is computed (annotation files, whose content is their
    key, are committed): the placeholders carry the keys the train stage's key needs.
    `fingerprints` stand in for recordings not on disk (planning only: the shipped
    model's lock, `sonarmap.pipeline.training.shipped`).
    """
    from sonarmap.pipeline.training.annotations import (
        ANNOTATIONS_STAGE,
        annotation_path,
        commit_annotations,
    )

    reading = _reading_graph()
    upstream = reading.stages
    external: dict[str, tuple[Stage, ArtifactRef]] = {}
    annotated = []
    # Validate every annotation file before any dataset is read: a typo fails in a second.
    pre = [_prefix(i, len(datasets), heldout) for i in range(len(datasets))]
    for i, path in enumerate(datasets):
        ann = annotation_path(path)
        if ann is not None:
            log.info("%s: labels from %s", path, ann)
            table = getattr(config, "classes", DEFAULT_TABLE)
            committed = commit_annotations(ann, store, table)
            external[f"{pre[i]}annotations_{i}"] = (ANNOTATIONS_STAGE, committed)
            annotated.append(i)
    first = None
    for i, path in enumerate(datasets):
        if fingerprints and path in fingerprints:
            assert not compute, "a locked fingerprint cannot be computed on"
            spec = DatasetSpec(path, fingerprints[path], _not_on_disk(path), reading.codecs)
        else:
            spec = dataset_spec(path, store, reading)
        first = first or spec
        planned = plan(upstream, config, spec, store)
        if compute:
            refs = execute(planned, config, spec, store).artifacts
        else:
            refs = {
                p.stage.name: ArtifactRef(
                    p.stage.name, p.key, store.artifact_dir(p.stage.name, p.key), {}
                )
                for p in planned
            }
        for stage in upstream:
            external[f"{pre[i]}{stage.name}_{i}"] = (stage, refs[stage.name])
    assert first is not None
    train = training_stage_for(len(datasets), annotated, [str(p) for p in datasets], heldout)
    return train, external, first


def _reading_graph() -> Graph:
    """What training reads of the real pipeline: each dataset's keyframes and features,
    the recording found and opened by the readers, `frames` stored by their codec."""
    from sonarmap.pipeline.formats.frames_codec import FRAMES_CODECS
    from sonarmap.pipeline.readers import dataset_fingerprint_parts, open_recording
    from sonarmap.stages.features import STAGE as features
    from sonarmap.stages.keyframes import STAGE as keyframes

    return Graph(
        (keyframes, features), dataset_fingerprint_parts, open_recording, codecs=FRAMES_CODECS
    )


def dataset_fingerprints(paths: Iterable[Path], store: ArtifactStore) -> dict[Path, str]:
    """{path: dataset fingerprint} of training recordings on disk, as training plans them
    (cached in `store` by size, mtime and inode)."""
    reading = _reading_graph()
    return {p: dataset_spec(p, store, reading).fingerprint for p in paths}


def _not_on_disk(path: Path) -> Callable[[Path, Any], Any]:
    def refuse(_path: Path, _section: Any) -> Any:
        raise SourceError(f"{path}: planned from the shipped model's lock, not simulated yet")

    return refuse


def plan_training(
    datasets: Sequence[Path],
    config: BaseModel,
    store: ArtifactStore,
    *,
    fingerprints: Mapping[Path, str] | None = None,
    heldout: int = 0,
) -> str:
    """The `train` key `train_on` would produce, computing nothing (training datasets'
    fingerprints are cached, or given by `fingerprints` for recordings not on disk;
    their keyframes and features are only planned). `heldout`: as `train_on`."""
    config = training_config(config)
    train, external, first = _bind_training(
        datasets, config, store, compute=False, fingerprints=fingerprints, heldout=heldout
    )
    return plan((train,), config, first, store, external=external)[0].key


def train_on(
    datasets: Sequence[Path], config: BaseModel, store: ArtifactStore, *, heldout: int = 0
) -> ArtifactRef:
    """Run keyframes + features on each dataset, then the train stage; return the model artifact.

    The last `heldout` datasets only validate (whole worlds held out; `training_stage_for`).

    Keyframes and features use the `training` section's settings (`training_config`). A
    dataset with an annotation file beside it (`sonarmap.pipeline.training.annotations.annotation_path`)
    is labelled by that file; the others need label images (simulated recordings).

    Raises:
        SourceError: an annotation file is unreadable or invalid (one line, file and field).
    """
    config = training_config(config)
    train, external, first = _bind_training(datasets, config, store, compute=True, heldout=heldout)
    planned = plan((train,), config, first, store, external=external)
    log.info("classifier: %s (%s)", "cached" if planned[0].hit else "training", planned[0].reason)
    result = execute(planned, config, first, store, external=external)
    if planned[0].hit:  # a computed model logged its warnings as it trained
        for line in result.warnings:
            log.warning("%s", line)
    return result.artifacts["train"]


def training_simulations(training: TrainingDataConfig) -> list[Simulation]:
    """The simulated missions of `training.sets`, then the procedural worlds of
    `training.procedural` (training, then held-out), with the files they are kept in."""
    from sonarmap.pipeline.training.datasets import scene_path
    from sonarmap.pipeline.training.worlds import procedural_simulations

    sims = []
    for item in training.sets:
        scene = scene_path(item.scene)
        suffix = f"-{item.duration_s:g}s" if item.duration_s else ""
        if item.sonars:  # one file per sensor pair; the clean sensor's name is unchanged
            names = dict.fromkeys(item.sonars[s] for s in sorted(item.sonars))
            suffix += "-" + "-".join(names)
        name = f"{scene.stem}-seed{item.seed}-goals{item.goals}{suffix}.mcap"
        sims.append(
            Simulation(
                scene, item.seed, Path(training.directory) / name, item.goals, item.duration_s,
                sonars=item.sonars,
            )
        )  # fmt: skip
    return sims + procedural_simulations(training)


def ordered_datasets(
    simulated: Sequence[Path], training: TrainingDataConfig
) -> tuple[list[Path], int]:
    """The default model's datasets in the train stage's order and how many (the last)
    are held out: the simulations' training recordings, `training.recorded`, then the
    held-out worlds.

    Raises:
        SourceError: a recorded dataset without its annotation file.
    """
    from sonarmap.pipeline.training.worlds import heldout_count

    k = heldout_count(training)
    cut = len(simulated) - k
    return [*simulated[:cut], *recorded_datasets(training), *simulated[cut:]], k


def training_datasets(training: TrainingDataConfig) -> list[Path]:
    """The default model's datasets (simulated on first use) in `ordered_datasets` order;
    the last `sonarmap.pipeline.training.worlds.heldout_count` of them validate.

    Raises:
        SourceError: a recorded dataset without its annotation file.
    """
    from sonarmap.pipeline.training.datasets import ensure_simulations

    workers = max(1, min(2, os.cpu_count() or 1))
    paths = ensure_simulations(training_simulations(training), workers)
    return ordered_datasets(paths, training)[0]


def recorded_datasets(training: TrainingDataConfig) -> list[Path]:
    """`training.recorded`, each checked for its annotation file.

    Raises:
        SourceError: a recorded dataset without its annotation file.
    """
    from sonarmap.pipeline.training.annotations import annotation_path

    paths = []
    for recorded in training.recorded:
        path = Path(recorded)
        if annotation_path(path) is None:
            raise SourceError(
                f"training.recorded: {path} has no {path.stem}.annotations.yaml beside it"
            )
        paths.append(path)
    return paths
