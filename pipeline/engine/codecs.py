"""Writing and reading stage outputs by kind (parquet, json, bytes, frames).

Parquet files are written deterministically: the table as the stage returns it
(stages sort their rows), zstd, and only key-derived metadata (stage, version, key)
in the schema, never timestamps, so the same inputs give the same bytes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, MutableSet, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import (
    ArtifactCorrupt,
    InternalError,
    PipelineError,
    StageFailed,
)
from sonarmap.stages.base import Output

if TYPE_CHECKING:
    import pyarrow as pa

    from sonarmap.pipeline.engine.store import ArtifactRef

__all__ = ["read_output", "read_verified", "validate_table", "write_output"]


def validate_table(stage: str, output: Output, table: Any) -> pa.Table:
    """Check a parquet output against its declared schema (names and types)."""
    import pyarrow as pa  # here: reading a JSON output (a cached run's summary) needs none

    if not isinstance(table, pa.Table):
        raise StageFailed(
            f"stage {stage}: output '{output.name}' must be a pyarrow.Table, "
            f"got {type(table).__name__}"
        )
    expected = output.arrow_schema
    if expected is None:
        return table
    missing = [f.name for f in expected if f.name not in table.column_names]
    if missing:
        raise StageFailed(f"stage {stage}: output '{output.name}' lacks columns {missing}")
    wrong = [
        f"{f.name}: {table.schema.field(f.name).type} != {f.type}"
        for f in expected
        if not table.schema.field(f.name).type.equals(f.type)
    ]
    if wrong:
        raise StageFailed(f"stage {stage}: output '{output.name}' column types {wrong}")
    return table


def write_output(
    directory: Path, stage: str, output: Output, value: Any, provenance: Mapping[str, str]
) -> dict[str, Any]:
    """Write one output into an artifact directory; returns manifest facts (rows, ...)."""
    path = directory / output.filename
    if output.kind == "parquet":
        import pyarrow.parquet as pq

        table = validate_table(stage, output, value)
        meta = dict(table.schema.metadata or {})
        meta[b"sonarmap"] = json.dumps(dict(provenance), sort_keys=True).encode()
        pq.write_table(table.replace_schema_metadata(meta), path, compression="zstd")
        return {"rows": table.num_rows}
    if output.kind == "json":
        path.write_text(json.dumps(value, indent=2, sort_keys=True, allow_nan=False) + "\n")
        # A JSON output's "warnings" (lines a stage found about its own result) go into the
        # manifest, where the run's output checks print them (`output_checks.stage_warnings`).
        found = value.get("warnings") if isinstance(value, dict) else None
        return {"warnings": [str(w) for w in found]} if isinstance(found, list) and found else {}
    if output.kind == "bytes":
        if not isinstance(value, (bytes, bytearray, memoryview)):
            raise StageFailed(f"stage {stage}: output '{output.name}' must be bytes")
        path.write_bytes(bytes(value))
        return {"bytes": len(value)}
    if output.kind == "frames":
        from sonarmap.pipeline.formats.frames_io import write_frames

        return {"frames": write_frames(value, path)}
    raise InternalError(f"stage {stage}: unknown output kind {output.kind!r}")


def read_verified(
    ref: ArtifactRef,
    output: Output,
    verified: MutableSet[tuple[str, str, str]] | None = None,
    columns: Sequence[str] | None = None,
) -> Any:
    """Read one output of a committed artifact after checking it against the manifest.

    `verified` remembers (stage, key, file) already hashed in this run, so a file
    bound by several stages costs one hash. A file the manifest does not list is
    never read, even if one lies on disk. `columns`: read only these of a Parquet
    output (the whole file is still verified).
    """
    from sonarmap.pipeline.engine.integrity import recovery_hint, verify_file

    name = output.filename
    if name not in ref.manifest["files"]:
        if output.optional:
            return None
        raise ArtifactCorrupt(
            f"artifact {ref.stage}/{ref.key[:12]}: its manifest lists no '{name}'; "
            f"{recovery_hint(ref.stage)}"
        )
    tag = (ref.stage, ref.key, name)
    if verified is None or tag not in verified:
        verify_file(ref, name)
        if verified is not None:
            verified.add(tag)
    try:
        return read_output(ref.path, output, columns)
    except PipelineError:
        raise
    except (OSError, ValueError) as err:
        # pyarrow's ArrowInvalid and json's errors are ValueErrors.
        reason = (str(err).splitlines() or [type(err).__name__])[0]
        raise ArtifactCorrupt(
            f"artifact {ref.stage}/{ref.key[:12]}: '{name}' does not parse as {output.kind} "
            f"({reason}); {recovery_hint(ref.stage)}"
        ) from err


def read_output(directory: Path, output: Output, columns: Sequence[str] | None = None) -> Any:
    """Read one output back; an optional output that was not written reads as None."""
    path = directory / output.filename
    if not path.exists():
        if output.optional:
            return None
        raise InternalError(f"{directory}: output file '{output.filename}' missing")
    if output.kind == "parquet":
        import pyarrow.parquet as pq

        return pq.read_table(path, columns=None if columns is None else list(columns))
    if output.kind == "json":
        return json.loads(path.read_text())
    if output.kind == "bytes":
        return path.read_bytes()
    if output.kind == "frames":
        from sonarmap.pipeline.formats.frames_io import read_frames

        return read_frames(path)
    raise InternalError(f"unknown output kind {output.kind!r}")
