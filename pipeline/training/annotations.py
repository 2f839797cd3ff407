"""Annotation files beside field recordings: find, read, validate, and key them.

`<stem>.annotations.yaml` (or `.json`) next to a recording labels its keyframes for
classifier training (format: `sonarmap.schemas.annotations`). The validated content is
committed to the store as a small "annotations" artifact keyed by its hash, which
`train` takes as an input: editing the shapes retrains, reformatting the file or
editing its comments does not.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.hashing import recipe_key
from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef, ArtifactStore
from sonarmap.pipeline.engine.text import one_line
from sonarmap.schemas.annotations import AnnotationFile
from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.stages.base import Output, Stage, StageConfig
from sonarmap.stages.classify.config import RASTER_VERSION

__all__ = ["ANNOTATIONS_STAGE", "annotation_path", "commit_annotations", "load_annotations"]

SUFFIXES = (".annotations.yaml", ".annotations.yml", ".annotations.json")

ANNOTATIONS_MAX_BYTES = 4 << 20
"""Largest annotation file read."""

ANNOTATIONS_MAX_NODES = 150_000
"""Most YAML values in an annotation file: some 8,000 keyframes of one box each (18
values), far beyond what is drawn by hand, and parsed in a few seconds."""


def _never_run(config: Any, inputs: Any) -> dict[str, Any]:  # pragma: no cover
    raise AssertionError("annotations artifacts are committed by commit_annotations")


ANNOTATIONS_STAGE = Stage(
    name="annotations",
    version=RASTER_VERSION,
    config=StageConfig,
    inputs=(),
    outputs=(Output("annotations", "json", "annotations.json"),),
    run=_never_run,
    description="a validated annotation file (bound to train as an external input)",
)
"""Describes the artifact for the engine's input binding; it is never planned."""


def annotation_path(dataset: Path) -> Path | None:
    """The annotation file beside a recording (`<stem>.annotations.yaml`), if any.

    Raises:
        SourceError: more than one of the accepted names exists.
    """
    found = [p for p in (dataset.parent / f"{dataset.stem}{s}" for s in SUFFIXES) if p.is_file()]
    if len(found) > 1:
        raise SourceError(f"{dataset}: several annotation files ({', '.join(map(str, found))})")
    return found[0] if found else None


def _message(err: ValidationError, path: Path) -> str:
    first = err.errors()[0]
    loc = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in first["loc"]).lstrip(".")
    msg = one_line(str(first["msg"]).removeprefix("Value error, "), 200)
    more = f" (and {err.error_count() - 1} more)" if err.error_count() > 1 else ""
    return f"{one_line(str(path))}: {one_line(loc, 80) or 'file'}: {msg}{more}"


def load_annotations(path: Path, table: ClassTable = DEFAULT_TABLE) -> AnnotationFile:
    """Read and validate an annotation file (class names against `table`, the config's
    class table).

    Raises:
        SourceError: unreadable, not YAML/JSON, refused by the bounded loader (aliases,
            duplicate keys, depth, huge integers, over ANNOTATIONS_MAX_BYTES or
            ANNOTATIONS_MAX_NODES), or invalid;
            one line naming the file and the field (e.g. `keyframes[2].objects[0].class_name`).
    """
    from sonarmap.pipeline.engine.config.yaml_files import (
        read_model,  # yaml: only when a file is read
    )

    return read_model(
        path,
        "annotations",
        AnnotationFile,
        SourceError,
        lambda err: _message(err, path),
        "expected a mapping with 'format' and 'keyframes'",
        ANNOTATIONS_MAX_BYTES,
        ANNOTATIONS_MAX_NODES,
        {"classes": table},
    )


def commit_annotations(
    path: Path, store: ArtifactStore, table: ClassTable = DEFAULT_TABLE
) -> ArtifactRef:
    """Validate an annotation file and store its content as an "annotations" artifact.

    The key hashes the validated content and the rasterisation version, so the train
    stage reading it retrains exactly when a shape, class or time changes.
    """
    from sonarmap.pipeline.engine.store.codecs import (
        write_output,  # pyarrow: not on a cached run's path
    )

    doc = load_annotations(path, table).model_dump(mode="json")
    recipe = {"stage": ANNOTATIONS_STAGE.name, "version": RASTER_VERSION, "doc": doc}
    key = recipe_key(recipe)
    output = ANNOTATIONS_STAGE.outputs[0]

    def build(tmp: Path) -> dict[str, Any]:
        write_output(tmp, ANNOTATIONS_STAGE.name, output, doc, {"key": key})
        return {}

    # The recipe lets `pull` check the key against the content, as for every stage.
    extra = {"version": RASTER_VERSION, "source": str(path), "recipe": recipe}
    ref = store.commit(ANNOTATIONS_STAGE.name, key, build, extra)
    # A run record per file keeps its newest artifact from `sonarmap gc`, like any run's.
    source = str(path.resolve())
    record = {
        "dataset": source,
        "updated_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "stages": {ANNOTATIONS_STAGE.name: {"key": key, "recipe": {"source": source}}},
    }
    store.record_run(recipe_key({"annotations": source})[:20], record)
    return ref
