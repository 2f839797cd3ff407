"""Run-level guard against empty maps: row counts of each stage's outputs, checked
as the stage commits (or is found cached).

The counts come from the manifests (`outputs.<name>.rows`, written at commit), so a
check reads no data. One table says, per stage, which counts are suspicious and the
likely cause; a check marked `fatal` ends the run with exit 2 once what was computed
is committed (a run that produces no map).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.store.artifact import ArtifactRef
from sonarmap.stages.keyframes.recording_name import with_path

__all__ = [
    "CHECKS",
    "EmptyMap",
    "OutputCheck",
    "check_stage",
    "output_rows",
    "recording_warnings",
    "stage_warnings",
]

Rows = Mapping[str, int]
"""Row counts by "stage.output" of the artifacts this run has so far."""


class EmptyMap(SourceError):
    """The run produced no map: every stage ran, but the input gave nothing to map."""


@dataclass(frozen=True)
class OutputCheck:
    """After `stage`, warn with `message` (formatted with the counts) when `applies`."""

    stage: str
    applies: Callable[[Rows], bool]
    message: str
    fatal: bool = False


def _n(rows: Rows, name: str) -> int:
    return rows.get(name, -1)


CHECKS: tuple[OutputCheck, ...] = (
    OutputCheck(
        "keyframes",
        lambda r: 0 <= _n(r, "keyframes.keyframes") < 2,
        "keyframes: {keyframes.keyframes} keyframes (a map needs at least 2): the vehicle may "
        "not have moved keyframes.spacing_m or turned keyframes.rotation_deg, or the pings "
        "may have no beams, empty images or invalid ranges, or all share one timestamp",
    ),
    OutputCheck(
        "features",
        lambda r: _n(r, "features.features") == 0 and _n(r, "keyframes.keyframes") > 0,
        "features: 0 features from {keyframes.keyframes} keyframes: the images may be "
        "empty or all below the detection threshold",
    ),
    OutputCheck(
        "fuse",
        lambda r: _n(r, "fuse.fused") == 0 and _n(r, "features.features") > 0,
        "fuse: 0 fused points from {features.features} features: no feature of one sonar"
        " matched one of the other in its keyframe (fans that do not overlap: check the two"
        " mounts; or fuse.min_confidence / fuse.max_cost_ratio culled every match)",
    ),
    OutputCheck(
        "slam",
        lambda r: 0 <= _n(r, "slam.poses") < 2 and _n(r, "keyframes.keyframes") >= 2,
        "slam: {slam.poses} poses from {keyframes.keyframes} keyframes",
    ),
    OutputCheck(
        "voxelize",
        lambda r: _n(r, "voxelize.map") == 0,
        "no map: voxelize's map has 0 points ({keyframes.keyframes} keyframes, "
        "{features.features} features, {fuse.fused} fused points)",
        fatal=True,
    ),
)


def output_rows(refs: Mapping[str, ArtifactRef]) -> dict[str, int]:
    """Row counts by "stage.output", from the manifests of `refs` (parquet outputs)."""
    rows: dict[str, int] = {}
    for name, ref in refs.items():
        outputs = ref.manifest.get("outputs")
        for out, facts in (outputs if isinstance(outputs, Mapping) else {}).items():
            if isinstance(facts, Mapping) and isinstance(facts.get("rows"), int):
                rows[f"{name}.{out}"] = facts["rows"]
    return rows


_FIELD = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*\.[A-Za-z_][A-Za-z0-9_]*)\}")


def _fill(message: str, rows: Rows) -> str:
    """`message` with each "{stage.output}" replaced by its row count ("?" if unknown)."""
    return _FIELD.sub(lambda m: str(rows.get(m.group(1), "?")), message)


def stage_warnings(ref: ArtifactRef | None) -> list[str]:
    """The warnings a stage wrote about its own result (a JSON output's "warnings", kept in
    the manifest by `sonarmap.pipeline.engine.store.codecs.write_output`), in output order."""
    outputs = None if ref is None else ref.manifest.get("outputs")
    found: list[str] = []
    for facts in (outputs if isinstance(outputs, Mapping) else {}).values():
        lines = facts.get("warnings") if isinstance(facts, Mapping) else None
        if isinstance(lines, list):
            found.extend(w for w in lines if isinstance(w, str))
    return found


def check_stage(
    stage: str, refs: Mapping[str, ArtifactRef], checks: tuple[OutputCheck, ...] | None = None
) -> list[tuple[str, bool]]:
    """(message, fatal) for every check (default: `CHECKS`) of `stage` that applies to
    the counts so far, then the stage's own warnings (`stage_warnings`, never fatal)."""
    rows = output_rows(refs)
    found = [(w, False) for w in stage_warnings(refs.get(stage))] if checks is None else []
    for check in CHECKS if checks is None else checks:
        if check.stage == stage and check.applies(rows):
            found.append((_fill(check.message, rows), check.fatal))
    return found


UNPAIRED_WARN_SHARE = 0.5
"""`recording_warnings` warns when more than this share of the horizontal pings find no
vertical ping within `keyframes.pair_tolerance_s`: keyframes are chosen among pairs only,
so most of the horizontal sonar's pings are then lost to the map (a vertical sonar that
pings less often, or clocks that are offset)."""
_SENSORS_MAX_BYTES = 4 << 20


def recording_warnings(ref: ArtifactRef | None, cached: bool, recording: str) -> list[str]:
    """What the keyframes artifact's `sensors.json` says the recording lost: most
    horizontal pings without a vertical partner; and, when the artifact was not computed
    by this process (`cached`), the reader's warnings (substitutions and drops) that the
    reader logged only when it read the recording, so that a cached run warns as the
    first run did, naming the `recording` of this run where they name it (`RECORDING`)."""
    if ref is None:
        return []
    path = ref.path / "sensors.json"
    try:
        if path.stat().st_size > _SENSORS_MAX_BYTES:
            return []
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return []  # verified with the artifact when a stage reads it
    if not isinstance(doc, Mapping):
        return []
    found: list[str] = []
    pairing = doc.get("pairing")
    if isinstance(pairing, Mapping):
        h = pairing.get("horizontal_pings")
        lost = pairing.get("unpaired_horizontal")
        if (
            isinstance(h, int)
            and isinstance(lost, int)
            and h > 0
            and lost > UNPAIRED_WARN_SHARE * h
        ):
            found.append(
                f"keyframes: {lost} of {h} horizontal pings have no vertical ping within "
                f"keyframes.pair_tolerance_s ({pairing.get('vertical_pings', '?')} vertical "
                f"pings): keyframes are chosen among the {pairing.get('pairs', '?')} pairs "
                "only (a vertical sonar that pings less often, or offset clocks)"
            )
    source = doc.get("source")
    lines = source.get("warnings") if isinstance(source, Mapping) and cached else None
    if isinstance(lines, list):
        found.extend(with_path(line, recording) for line in lines if isinstance(line, str))
    return found
