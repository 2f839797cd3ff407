"""The shape of `manifest.json`, validated before the store trusts any field of it.

A manifest is what makes an artifact exist, so a hand-edited, truncated or foreign
one must be refused in one line instead of crashing whoever reads it (`run`, `show`,
`ls`, `gc`, `pull`). Only the fields the engine reads are typed; the rest (config,
software versions, timings, output facts) pass through untouched.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from sonarmap.pipeline.engine.errors import ArtifactCorrupt

__all__ = ["ADDRESS_PATTERN", "FileEntry", "Manifest", "parse_manifest", "read_manifest"]

# "<stage>/<key>": a stage identifier and a lowercase hex key, nothing that could
# walk out of a store or remote (no "..", no absolute path, no separators in the key).
ADDRESS_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*/[0-9a-f]{1,64}$"


_Key = Annotated[str, Field(pattern=r"^[0-9a-f]{1,64}$")]
_Address = Annotated[str, Field(pattern=ADDRESS_PATTERN)]


class FileEntry(BaseModel):
    """One file of an artifact as the manifest lists it."""

    # Unknown keys are ignored: a newer writer may add some, and a listed file must not
    # become "broken" (and collectable) for that.
    model_config = ConfigDict(frozen=True, extra="ignore", strict=True)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    size: int = Field(ge=0)


class Manifest(BaseModel):
    """The fields of `manifest.json` the engine relies on."""

    model_config = ConfigDict(frozen=True, extra="allow")
    stage: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")
    key: _Key
    files: dict[str, FileEntry]
    recipe: dict[str, Any] | None = None
    inputs: dict[str, _Key] = Field(default_factory=dict)
    input_artifacts: dict[str, _Address] = Field(default_factory=dict)
    created_at: str = ""


def _first_problem(err: ValidationError) -> str:
    e = err.errors()[0]
    where = ".".join(str(p) for p in e["loc"]) or "manifest"
    return f"{where}: {e['msg']}"


def parse_manifest(raw: Any, where: str) -> Manifest:
    """Validate an already decoded manifest; `where` names it in the one-line error."""
    if not isinstance(raw, dict):
        raise ArtifactCorrupt(f"{where}: manifest is a JSON {type(raw).__name__}, not an object")
    try:
        return Manifest.model_validate(raw)
    except ValidationError as err:
        raise ArtifactCorrupt(f"{where}: invalid manifest ({_first_problem(err)})") from err


def read_manifest(path: Path) -> tuple[Manifest, dict[str, Any]]:
    """The validated model and the raw dict of a manifest file.

    Raises:
        FileNotFoundError: there is no manifest (the directory is not an artifact).
        ArtifactCorrupt: unreadable, not JSON, or not a valid manifest.
    """
    try:
        raw = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise
    except (OSError, ValueError) as err:
        raise ArtifactCorrupt(f"{path}: unreadable manifest ({err})") from err
    return parse_manifest(raw, str(path)), raw
