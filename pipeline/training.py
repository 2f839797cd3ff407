"""The default classifier: trained on simulated scenes other than the one being mapped.

Training is an ordinary cached stage. Each training dataset goes through the graph up
to `features` (cached per dataset like any run); the `train` stage then reads all of
them, so its key covers every dataset's keyframes and features, the train config, and
the stage version. `sonarmap run` binds the resulting `model.pt` to `classify`'s
"train.model" input; a warm store trains nothing.

A recording with an annotation file beside it (`<stem>.annotations.yaml`, format in
`schemas.annotations`) is labelled by that file instead of label images: its content
becomes an "annotations" artifact that `train` also reads, so editing it retrains.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, field_validator

from pipeline.errors import ConfigError
from pipeline.runner import execute, plan
from pipeline.session import dataset_spec
from pipeline.store import ArtifactRef, ArtifactStore
from schemas.sonar import KeyframeImages
from stages.base import ConfigModel, Stage

__all__ = [
    "TrainingDataConfig",
    "TrainingSet",
    "resolve_model",
    "train_on",
    "training_stage_for",
]

log = logging.getLogger(__name__)


class TrainingSet(ConfigModel):
    """One simulated mission the default classifier learns from."""

    scene: str = Field(min_length=1, description="a scene name in configs/scenes/ or a file")
    seed: int = Field(ge=0, le=2**32 - 1)
    goals: int = Field(ge=1, le=10000)
    duration_s: float | None = Field(None, gt=0, le=7 * 86400)

    @field_validator("scene")
    @classmethod
    def _scene_exists(cls, value: str) -> str:
        # Checked with the rest of the config, not when training first needs it.
        from pipeline.datasets import scene_path

        try:
            scene_path(value)
        except ConfigError as err:
            raise ValueError(str(err)) from err
        return value


class TrainingDataConfig(ConfigModel):
    """Config section `training`: which labelled datasets the default model is trained on.

    The mapped scene should not be among them (the default marina never is). Seeds are
    far from the study's 0..N-1. Simulated files go to `directory` and are reused.
    """

    sets: tuple[TrainingSet, ...] = (
        TrainingSet(scene="harbour", seed=100, goals=12, duration_s=None),
        TrainingSet(scene="pier", seed=101, goals=6, duration_s=None),
    )
    directory: str = Field("data/training", min_length=1)
    recorded: tuple[str, ...] = Field(
        default=(),
        description="field recordings to train on too; each needs <stem>.annotations.yaml beside it",
    )


def training_stage_for(
    n_datasets: int, annotated: Sequence[int] = (), names: Sequence[str] = ()
) -> Stage:
    """The `train` stage reading `n_datasets` (keyframes, features) pairs.

    Inputs are bound as "keyframes_i.frames" / "features_i.features" so one stage run
    sees every dataset; dataset i in `annotated` also reads "annotations_i.annotations"
    and is labelled by it (`stages.annotations.label_keyframes`) instead of label
    images. `names` (the datasets' paths) only word error messages. Outputs and config
    are those of `stages.train`.
    """
    from pipeline.registry import training_stage
    from schemas.annotations import AnnotationFile
    from stages.annotations import label_keyframes
    from stages.train import train_classifier

    base = training_stage()
    inputs = tuple(
        name
        for i in range(n_datasets)
        for name in (
            f"keyframes_{i}.frames",
            f"features_{i}.features",
            *([f"annotations_{i}.annotations"] if i in annotated else []),
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
        kf = bound[f"keyframes_{i}.frames"]
        if i not in annotated:
            return labelled(i, kf)
        doc = AnnotationFile.model_validate(bound[f"annotations_{i}.annotations"])
        return label_keyframes(kf, doc, source=f"annotations of {name(i)}")

    def run(config: Any, bound: Mapping[str, Any]) -> Mapping[str, Any]:
        pairs = [(frames(i, bound), bound[f"features_{i}.features"]) for i in range(n_datasets)]
        return train_classifier(pairs, config)

    return Stage(base.name, base.version, base.config, inputs, base.outputs, run, base.description)


def train_on(datasets: Sequence[Path], config: BaseModel, store: ArtifactStore) -> ArtifactRef:
    """Run keyframes + features on each dataset, then the train stage; return the model artifact.

    A dataset with an annotation file beside it (`pipeline.annotations.annotation_path`)
    is labelled by that file; the others need label images (simulated recordings).

    Raises:
        SourceError: an annotation file is unreadable or invalid (one line, file and field).
    """
    from pipeline.annotations import ANNOTATIONS_STAGE, annotation_path, commit_annotations
    from pipeline.registry import pipeline_stages

    upstream = pipeline_stages()[:2]
    external: dict[str, tuple[Stage, ArtifactRef]] = {}
    annotated = []
    # Validate every annotation file before any dataset is read: a typo fails in a second.
    for i, path in enumerate(datasets):
        ann = annotation_path(path)
        if ann is not None:
            log.info("%s: labels from %s", path, ann)
            external[f"annotations_{i}"] = (ANNOTATIONS_STAGE, commit_annotations(ann, store))
            annotated.append(i)
    first = None
    for i, path in enumerate(datasets):
        spec = dataset_spec(path, store)
        first = first or spec
        result = execute(plan(upstream, config, spec, store), config, spec, store)
        for stage in upstream:
            external[f"{stage.name}_{i}"] = (stage, result.artifacts[stage.name])
    assert first is not None
    train = training_stage_for(len(datasets), annotated, [str(p) for p in datasets])
    planned = plan((train,), config, first, store, external=external)
    log.info("classifier: %s (%s)", "cached" if planned[0].hit else "training", planned[0].reason)
    return execute(planned, config, first, store, external=external).artifacts["train"]


def resolve_model(store: ArtifactStore, config: BaseModel) -> tuple[Stage, ArtifactRef]:
    """The default model for `classify`: simulate the training scenes if needed, train if needed."""
    from pipeline.annotations import annotation_path
    from pipeline.datasets import ensure_simulation, scene_path
    from pipeline.errors import SourceError

    training: TrainingDataConfig = getattr(config, "training", TrainingDataConfig())
    paths = []
    for item in training.sets:
        scene = scene_path(item.scene)
        suffix = f"-{item.duration_s:g}s" if item.duration_s else ""
        out = (
            Path(training.directory)
            / f"{scene.stem}-seed{item.seed}-goals{item.goals}{suffix}.mcap"
        )
        paths.append(
            ensure_simulation(scene, item.seed, out, goals=item.goals, duration_s=item.duration_s)
        )
    for recorded in training.recorded:
        path = Path(recorded)
        if annotation_path(path) is None:
            raise SourceError(
                f"training.recorded: {path} has no {path.stem}.annotations.yaml beside it"
            )
        paths.append(path)
    ref = train_on(paths, config, store)
    annotated = [i for i, p in enumerate(paths) if annotation_path(p) is not None]
    return training_stage_for(len(paths), annotated), ref
