"""Writing and reading stage outputs by kind: the engine's own (parquet, json, bytes),
and any other through the `Codec` the graph supplies (the real pipeline's `frames`,
`sonarmap.pipeline.formats.frames_io`), so the engine imports no file format above it.

Parquet files are written deterministically: the table as the stage returns it
(stages sort their rows), zstd, and only key-derived metadata (stage, version, key)
in the schema, never timestamps, so the same inputs give the same bytes.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, MutableSet, Sequence
from dataclasses import dataclass
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

    from sonarmap.pipeline.engine.store.artifact_store import ArtifactRef

__all__ = ["Codec", "read_output", "read_verified", "validate_table", "write_output"]


@dataclass(frozen=True)
class Codec:
    """How outputs of one kind beyond the engine's own are stored (module-level functions,
    so a job carrying it travels to a worker process).

    Attributes:
        write: (value, path) -> the number of items written, recorded in the manifest
            under the kind's name (e.g. `"frames": 12`).
        read: path -> the value a reading stage binds.
    """

    write: Callable[[Any, Path], int]
    read: Callable[[Path], Any]


def _codec(kind: str, codecs: Mapping[str, Codec], where: str) -> Codec:
    codec = codecs.get(kind)
    if codec is None:
        raise InternalError(f"{where}: unknown output kind {kind!r} (no codec in the graph)")
    return codec


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
    directory: Path,
    stage: str,
    output: Output,
    value: Any,
    provenance: Mapping[str, str],
    codecs: Mapping[str, Codec] | None = None,
) -> dict[str, Any]:
    """Write one output into an artifact directory; returns manifest facts (rows, ...).
    `codecs`: the graph's, for kinds beyond parquet, json and bytes."""
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
    codec = _codec(output.kind, codecs or {}, f"stage {stage}")
    return {output.kind: codec.write(value, path)}


def read_verified(
    ref: ArtifactRef,
    output: Output,
    verified: MutableSet[tuple[str, str, str]] | None = None,
    columns: Sequence[str] | None = None,
    codecs: Mapping[str, Codec] | None = None,
) -> Any:
    """Read one output of a committed artifact after checking it against the manifest.

    `verified` remembers (stage, key, file) already hashed in this run, so a file
    bound by several stages costs one hash. A file the manifest does not list is
    never read, even if one lies on disk. `columns`: read only these of a Parquet
    output (the whole file is still verified). `codecs`: as for `read_output`.
    """
    from sonarmap.pipeline.engine.store.integrity import recovery_hint, verify_file

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
        return read_output(ref.path, output, columns, codecs)
    except PipelineError:
        raise
    except (OSError, ValueError) as err:
        # pyarrow's ArrowInvalid and json's errors are ValueErrors.
        reason = (str(err).splitlines() or [type(err).__name__])[0]
        raise ArtifactCorrupt(
            f"artifact {ref.stage}/{ref.key[:12]}: '{name}' does not parse as {output.kind} "
            f"({reason}); {recovery_hint(ref.stage)}"
        ) from err


def read_output(
    directory: Path,
    output: Output,
    columns: Sequence[str] | None = None,
    codecs: Mapping[str, Codec] | None = None,
) -> Any:
    """Read one output back; an optional output that was not written reads as None.
    `codecs`: the graph's, for kinds beyond parquet, json and bytes."""
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
    return _codec(output.kind, codecs or {}, str(directory)).read(path)
