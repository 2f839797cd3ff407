"""Sonar geometry per sonar: named presets (`configs/sonars/*.yaml`) and beam-table files.

A sonar is described by its horizontal fan (`fov_deg`, outer beam edges), its vertical
aperture, its maximum range and, where the maker publishes one, its beam-angle table
(beam centres in image-column order, positive to the sonar's left). `load_sonar` takes a
preset name or the path of a CSV/TXT/YAML file of beam angles [deg].
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.package_data import configs_dir

__all__ = [
    "MAX_BEAMS",
    "PRESETS_DIR",
    "SonarModel",
    "even_beam_angles",
    "fov_of_table",
    "load_sonar",
    "preset_names",
]

PRESETS_DIR = configs_dir() / "sonars"
MAX_BEAMS = 4096
"""Largest beam table accepted (imaging sonars have at most a few hundred beams)."""
_MAX_TABLE_BYTES = 1 << 20
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


@dataclass(frozen=True)
class SonarModel:
    """One sonar's geometry.

    Attributes:
        name: preset name, or the table file's name.
        title: what it is (maker, model, mode).
        fov_deg: horizontal fan [deg], outer beam edges.
        max_range_m: maximum range [m] (None: not stated).
        vertical_aperture_deg: vertical (out-of-fan) aperture [deg] (None: not stated).
        beam_angles_deg: (n,) beam centres [deg] in image-column order, or None.
        source: "preset NAME" or "file PATH".
        datasheet: {"title", "url"} where the figures come from (empty for a file).
    """

    name: str
    title: str
    fov_deg: float
    max_range_m: float | None = None
    vertical_aperture_deg: float | None = None
    beam_angles_deg: np.ndarray | None = None
    source: str = ""
    datasheet: dict[str, str] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-able description (beam table summarised, not listed)."""
        out: dict[str, Any] = {"name": self.name, "source": self.source}
        if self.datasheet:
            out["datasheet"] = dict(self.datasheet)
        return out


def preset_names() -> list[str]:
    """Names of the shipped presets, sorted."""
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


def fov_of_table(angles_deg: np.ndarray) -> float:
    """Fan width [deg] of a table of beam centres: their span plus one mean spacing."""
    a = np.sort(np.asarray(angles_deg, np.float64))
    if len(a) < 2:
        return 0.0
    return float((a[-1] - a[0]) * len(a) / (len(a) - 1))


def even_beam_angles(fov_deg: float, n_beams: int) -> np.ndarray:
    """(n,) evenly spaced beam angles [rad], column 0 at +fov/2 (port), as Oculus images."""
    fov = np.deg2rad(fov_deg)
    return np.linspace(fov / 2, -fov / 2, n_beams)


def _checked_table(values: Any, where: str) -> np.ndarray:
    """A list of beam angles [deg] as (n,) float64, or ConfigError naming `where`."""
    try:
        a = np.asarray(values, np.float64)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{where}: beam angles must be numbers in degrees ({err})") from err
    if a.ndim != 1 or not 2 <= len(a) <= MAX_BEAMS:
        raise ConfigError(
            f"{where}: a beam table needs 2 to {MAX_BEAMS} angles in one list, got shape {a.shape}"
        )
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > 180.0):
        raise ConfigError(f"{where}: beam angles must be finite degrees within [-180, 180]")
    d = np.diff(a)
    if not (np.all(d > 0) or np.all(d < 0)):
        k = int(np.flatnonzero((d <= 0) if d[0] > 0 else (d >= 0))[0])
        raise ConfigError(
            f"{where}: beam angles must be strictly monotonic (beam {k + 1} = {a[k + 1]:.6g} "
            f"after {a[k]:.6g})"
        )
    return a


def _optional_float(doc: dict[str, Any], key: str, where: str) -> float | None:
    value = doc.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise ConfigError(f"{where}: {key} must be a positive number, got {str(value)[:20]!r}")
    return float(value)


def _from_mapping(doc: dict[str, Any], name: str, source: str, where: str) -> SonarModel:
    table = doc.get("beam_angles_deg")
    angles = None if table is None else _checked_table(table, f"{where} beam_angles_deg")
    fov = _optional_float(doc, "fov_deg", where)
    if fov is None and angles is None:
        raise ConfigError(f"{where}: needs fov_deg or beam_angles_deg")
    sheet = doc.get("datasheet") or {}
    return SonarModel(
        name=str(doc.get("name", name)),
        title=str(doc.get("title", name)),
        fov_deg=fov if fov is not None else fov_of_table(angles),  # type: ignore[arg-type]
        max_range_m=_optional_float(doc, "max_range_m", where),
        vertical_aperture_deg=_optional_float(doc, "vertical_aperture_deg", where),
        beam_angles_deg=angles,
        source=source,
        datasheet={k: str(sheet[k]) for k in ("title", "url") if k in sheet},
    )


def _text_table(path: Path, where: str) -> np.ndarray:
    """Numbers of a CSV/TXT file (commas, spaces or newlines; `#` comments; one header row)."""
    from sonarmap.pipeline.engine.config.yaml_files import _read_capped

    raw = _read_capped(path, "beam table", ConfigError, _MAX_TABLE_BYTES)
    values: list[str] = []
    header_allowed = True
    for k, line in enumerate(raw.decode("utf-8", "replace").splitlines()):
        tokens = [t for t in re.split(r"[,;\s]+", line.split("#", 1)[0]) if t]
        if not tokens:
            continue
        bad = [t for t in tokens if not _NUMBER.match(t)]
        if bad and header_allowed:
            header_allowed = False
            continue  # the first non-comment line may be a header ("angle_deg")
        header_allowed = False
        if bad:
            raise ConfigError(f"{where}:{k + 1}: {bad[0][:20]!r} is not a number of degrees")
        values.extend(tokens)
    return _checked_table([float(v) for v in values], where)


def _shown(spec: str, limit: int = 240) -> str:
    """The spec as a message shows it: whole when it is a plausible path, else its head and
    its tail (a file's name is at the end, so a plain cut would hide the part that matters)."""
    if len(spec) <= limit:
        return spec
    return f"{spec[: limit // 3]}…{spec[-(2 * limit) // 3 :]}"


@functools.lru_cache(maxsize=64)
def sonar_file(spec: str) -> tuple[Path, bool]:
    """The file a sonar setting names, and whether it is a shipped preset.

    Raises:
        ConfigError: neither a preset's name nor a file; one line naming it.
    """
    preset = PRESETS_DIR / f"{spec}.yaml"
    if re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", spec) and preset.is_file():
        return preset, True
    path = Path(spec)
    if not path.is_file():
        raise ConfigError(
            f"sonar {_shown(spec)!r}: neither a preset ({', '.join(preset_names())}) nor a "
            "beam-table file (.csv, .txt, .yaml)"
        )
    return path, False


def load_sonar(spec: str) -> SonarModel:
    """A preset by name, or a beam-table file (.csv/.txt: angles; .yaml: list or mapping).

    Raises:
        ConfigError: an unknown name, an unreadable file or a bad table; one line naming it.
    """
    from sonarmap.pipeline.engine.config.yaml_files import read_yaml

    path, is_preset = sonar_file(spec)
    if is_preset:
        doc = read_yaml(path, "sonar preset", ConfigError)
        return _from_mapping(doc, spec, f"preset {spec}", str(path))
    where = str(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        doc = read_yaml(path, "beam table", ConfigError)
        if isinstance(doc, list):
            doc = {"beam_angles_deg": doc}
        if not isinstance(doc, dict):
            raise ConfigError(f"{where}: a beam table is a list of angles or a mapping")
        return _from_mapping(doc, path.stem, f"file {path}", where)
    angles = _text_table(path, where)
    return SonarModel(
        name=path.stem,
        title=path.stem,
        fov_deg=fov_of_table(angles),
        beam_angles_deg=angles,
        source=f"file {path}",
    )
