"""Sound Metrics ARIS recordings (`.aris`, DDF_05): one sonar topic of frames.

Layout (the "Understanding ARIS data" page of the maker's aris-file-sdk): a 1024-byte file
header, then frames of a 1024-byte frame header followed by `BeamCount * SamplesPerBeam`
unsigned bytes, sample-major (row = one range sample across every beam; beam 0 is the
right-most). Every frame has the same size; the frame count is computed from the file
size, never taken from the header. The beam count follows from `PingMode`
(`get_beams_from_pingmode` of the maker's `FrameFuncs.c`); the bearings from the maker's
beam table for that beam count (presets `aris*-N`); the range window from each frame's
sound speed and sample timing:

    range[k] = (SampleStartDelay + k * SamplePeriod) [us] * 1e-6 * SoundSpeed / 2

Frames are read lazily: opening a file reads only the frame headers (in batches, keeping
just their times), so memory stays flat whatever the file's length.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.readers.aris_layout import (
    FILE_HEADER,
    FRAME_HEADER,
    FRAME_OFFSETS,
    HEADER_BYTES,
    SIGNATURE,
)
from sonarmap.pipeline.readers.clock import backwards
from sonarmap.pipeline.readers.sonar_models import load_sonar
from sonarmap.pipeline.readers.source_types import TimeIndexedSource

__all__ = [
    "ARIS_MAGIC",
    "ARIS_TOPIC",
    "ARIS_TYPE",
    "BEAMS_BY_PING_MODE",
    "ArisFrame",
    "ArisSource",
]

log = logging.getLogger(__name__)

ARIS_TOPIC = "/aris/frames"
ARIS_TYPE = "aris/Frame"
ARIS_MAGIC = SIGNATURE.to_bytes(4, "little")
"""The first 4 bytes of every ARIS file ("DDF" + 0x05)."""

BEAMS_BY_PING_MODE = {1: 48, 2: 48, 3: 96, 4: 96, 5: 96, 6: 64, 7: 64, 8: 64}
BEAMS_BY_PING_MODE.update({m: 128 for m in (9, 10, 11, 12)})
"""`get_beams_from_pingmode` (FrameFuncs.c)."""
_PRESET_BY_BEAMS = {48: "aris1800-48", 96: "aris1800-96", 64: "aris3000-64", 128: "aris3000-128"}
_SYSTEMS = {0: "ARIS 1800", 1: "ARIS 3000", 2: "ARIS 1200"}
_SYSTEM_BEAMS = {0: (48, 96), 1: (64, 128), 2: (48,)}
MAX_SAMPLES_PER_BEAM = 16384
"""ARIS sonars sample at most a few thousand times per beam; a header claiming more is
refused before anything is sized from it."""
_HEADER_BATCH = 1024
_MAX_FRAME_TIME_US = (2**63 - 1) // 1000
"""The latest FrameTime [us] whose time in ns fits the int64 every log time is."""
_SOUND_SPEED_MPS = (1300.0, 1800.0)
"""Sound speed in water, fresh to salt, cold to warm, with margin."""


def _field_at(frame: int, frame_bytes: int, name: str) -> int:
    """Byte offset in the file of a frame header field."""
    return HEADER_BYTES + frame * frame_bytes + FRAME_OFFSETS[name]


@dataclass(frozen=True)
class ArisFrame:
    """One decoded ARIS frame.

    Attributes:
        index: frame index in the file (0-based).
        image: (n_samples, n_beams) uint8, rows near -> far, column k = beam k
            (beam 0 right-most).
        ranges_m: (n_samples,) range of each sample [m] (the maker's SampleRange).
        angles_rad: (n_beams,) beam centres [rad], positive to the sonar's left.
        sound_speed_mps: the frame's sound speed [m/s].
        heading_deg, pitch_deg, roll_deg: the sonar's own compass output [deg].
        platform: the vehicle's heading/pitch/roll [deg] and depth [m] from the
            frame's AUV-integration fields; None when the recorder left them all zero.
    """

    index: int
    image: np.ndarray
    ranges_m: np.ndarray
    angles_rad: np.ndarray
    sound_speed_mps: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    platform: dict[str, float] | None


class ArisSource(TimeIndexedSource):
    """An ARIS file as a source with one topic, `/aris/frames` (type `aris/Frame`).

    Message times are the frame headers' `FrameTime` (PC time stamp, microseconds since
    the epoch), the recorder's clock like a bag's log time.
    """

    kind = "aris"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.warnings: list[str] = []
        self._file: BinaryIO | None = None
        size = path.stat().st_size
        if size < 2 * HEADER_BYTES:
            raise SourceError(
                f"{path}: {size} bytes; an ARIS file needs a {HEADER_BYTES}-byte file header "
                "and at least one frame"
            )
        with path.open("rb") as self._file:
            self._open_headers(size)
        self._file = None

    def _open_headers(self, size: int) -> None:
        """Read and check the file header and every frame header (file open)."""
        path = self.path
        head = np.frombuffer(self._read(0, HEADER_BYTES), FILE_HEADER, 1)[0]
        if int(head["Version"]) != SIGNATURE:
            raise SourceError(
                f"{path}: not an ARIS file (byte 0 holds {int(head['Version']):#010x}, "
                f"expected {SIGNATURE:#010x})"
            )
        first = np.frombuffer(self._read(HEADER_BYTES, HEADER_BYTES), FRAME_HEADER, 1)[0]
        self._check_first(first)
        mode = int(first["PingMode"])
        self.n_beams = BEAMS_BY_PING_MODE[mode]
        self.n_samples = int(first["SamplesPerBeam"])
        self.frame_bytes = HEADER_BYTES + self.n_beams * self.n_samples
        n, rest = divmod(size - HEADER_BYTES, self.frame_bytes)
        self.frames_misfit = bool(rest)
        if n == 0:
            raise SourceError(
                f"{path}: cut short: the first frame needs {self.frame_bytes} bytes from byte "
                f"{HEADER_BYTES} ({self.n_beams} beams x {self.n_samples} samples + header), "
                f"the file has {size - HEADER_BYTES}"
            )
        if rest:
            self._warn(
                f"{path}: the last {rest} bytes are not a whole frame (a frame is "
                f"{self.frame_bytes} bytes); frame {n} onwards is cut short and dropped, "
                f"{n} frames read"
            )
        system = int(first["TheSystemType"])
        self.system = _SYSTEMS.get(system, f"type {system}")
        self.table = load_sonar(_PRESET_BY_BEAMS[self.n_beams])
        times, telephoto = self._scan_headers(n, first)
        self._check_lens(telephoto, n, system)
        found = backwards(times)
        if found is not None:
            # A clock set back: the frames behind are dropped (sorted in, they would
            # interleave two passes over the scene).
            self._warn(found.warning(f"{path}: {ARIS_TOPIC}").replace("messages", "frames"))
            times = np.where(found.behind, -1, times)
        self._order = np.argsort(times, kind="stable")
        self._order = self._order[times[self._order] >= 0]
        self._frame_times = times
        self._set_topics(path, {ARIS_TOPIC: times[self._order]}, {ARIS_TOPIC: ARIS_TYPE}, None)

    def _read(self, offset: int, size: int) -> bytes:
        if self._file is not None:  # while opening: one handle for every header
            self._file.seek(offset)
            return self._file.read(size)
        with self.path.open("rb") as f:
            f.seek(offset)
            return f.read(size)

    def _scan_headers(self, n: int, first: np.void) -> tuple[np.ndarray, int]:
        """Check every frame header, in batches (memory flat in the frame count; the first
        bad frame stops the scan). Returns (n,) int64 frame times [ns] and the number of
        frames with a telephoto lens."""
        times = np.empty(n, np.int64)
        telephoto = 0
        for start in range(0, n, _HEADER_BATCH):
            k = range(start, min(n, start + _HEADER_BATCH))
            raw = b"".join(self._read(HEADER_BYTES + i * self.frame_bytes, HEADER_BYTES) for i in k)
            h = np.frombuffer(raw, FRAME_HEADER)
            self._check_frames(h, start, first)
            us = h["FrameTime"]
            over = us > _MAX_FRAME_TIME_US
            if over.any():
                k = start + int(np.flatnonzero(over)[0])
                raise SourceError(
                    f"{self.path}: frame {k} (byte {_field_at(k, self.frame_bytes, 'FrameTime')}"
                    f"): FrameTime {int(us[over][0])} us is past the year 2262, the latest "
                    "time a signed 64-bit count of ns holds (a corrupt or unset clock)"
                )
            times[start : start + len(h)] = us.astype(np.int64) * 1000
            telephoto += int(np.count_nonzero(h["LargeLens"]))
        return times, telephoto

    def _warn(self, message: str) -> None:
        # Collected, not logged: every command prints a source's warnings once.
        self.warnings.append(message)

    def _check_first(self, first: np.void) -> None:
        """Refuse a first frame header whose sizes cannot be trusted (file + byte offset)."""
        p = self.path
        if int(first["Version"]) != SIGNATURE:
            raise SourceError(
                f"{p}: byte {_field_at(0, 0, 'Version')}: frame 0 signature "
                f"{int(first['Version']):#010x}, expected {SIGNATURE:#010x} (corrupt file)"
            )
        mode = int(first["PingMode"])
        if mode not in BEAMS_BY_PING_MODE:
            raise SourceError(
                f"{p}: byte {_field_at(0, 0, 'PingMode')}: PingMode {mode} is not an ARIS "
                "ping mode (1-12), so the beam count is unknown"
            )
        samples = int(first["SamplesPerBeam"])
        if not 1 <= samples <= MAX_SAMPLES_PER_BEAM:
            raise SourceError(
                f"{p}: byte {_field_at(0, 0, 'SamplesPerBeam')}: SamplesPerBeam {samples} "
                f"(expected 1 to {MAX_SAMPLES_PER_BEAM})"
            )

    def _check_frames(self, h: np.ndarray, start: int, first: np.void) -> None:
        """Frames start.. : signature, same size as frame 0, ordered samples, sane timing."""
        misfit = (
            f" (frame 0's PingMode {int(first['PingMode'])} and SamplesPerBeam"
            f" {self.n_samples} make {self.frame_bytes}-byte frames, which do not divide the"
            " file: is one of them wrong?)"
            if self.frames_misfit
            else ""
        )
        checks = (
            (
                "Version",
                h["Version"] != SIGNATURE,
                f"signature, expected {SIGNATURE:#010x}{misfit}",
            ),
            ("PingMode", h["PingMode"] != first["PingMode"], "PingMode differs from frame 0's"),
            (
                "SamplesPerBeam",
                h["SamplesPerBeam"] != first["SamplesPerBeam"],
                "SamplesPerBeam differs from frame 0's (every ARIS frame has one size)",
            ),
            (
                "ReorderedSamples",
                h["ReorderedSamples"] == 0,
                "samples not yet reordered (a raw device capture, not a recording: reorder "
                "them with the maker's ARIS Integration SDK first)",
            ),
            ("SamplePeriod", h["SamplePeriod"] == 0, "SamplePeriod 0 us"),
            (
                "SoundSpeed",
                ~(
                    (h["SoundSpeed"] >= _SOUND_SPEED_MPS[0])
                    & (h["SoundSpeed"] <= _SOUND_SPEED_MPS[1])
                ),
                f"SoundSpeed outside {_SOUND_SPEED_MPS[0]:g}-{_SOUND_SPEED_MPS[1]:g} m/s",
            ),
        )
        for name, bad, what in checks:
            if bad.any():
                j = int(np.flatnonzero(bad)[0])
                value = h[name][j].item()
                shown = f"{value:#010x}" if name == "Version" else f"{value:.6g}"
                k = start + j
                raise SourceError(
                    f"{self.path}: frame {k} (byte {_field_at(k, self.frame_bytes, name)}): "
                    f"{name} {shown[:20]}: {what}"
                )

    def _check_lens(self, telephoto: int, n: int, system: int) -> None:
        """Warn where the bundled beam table may not be the sonar's own."""
        if self.n_beams not in _SYSTEM_BEAMS.get(system, (self.n_beams,)):
            self._warn(
                f"{self.path}: the frames say {self.system} but {self.n_beams} beams; "
                f"bearings from the {self.table.name} table (the only one with {self.n_beams})"
            )
        if telephoto:
            self._warn(
                f"{self.path}: {telephoto} of {n} frames say a telephoto lens "
                f"(LargeLens); no telephoto beam table is bundled, so bearings are from the "
                f"standard-lens table {self.table.name} (fan {self.table.fov_deg:.4g} deg); "
                "give the telephoto table as keyframes.horizontal_sonar (a CSV of angles)"
            )

    def frame(self, k: int) -> ArisFrame:
        """Decode frame k (0-based, file order)."""
        raw = self._read(HEADER_BYTES + k * self.frame_bytes, self.frame_bytes)
        if len(raw) != self.frame_bytes:
            raise SourceError(f"{self.path}: frame {k} was cut short while being read")
        h = np.frombuffer(raw, FRAME_HEADER, 1)[0]
        c = float(h["SoundSpeed"])
        start_us, period_us = float(h["SampleStartDelay"]), float(h["SamplePeriod"])
        ranges = (start_us + period_us * np.arange(self.n_samples)) * 1e-6 * c / 2.0
        image = np.frombuffer(raw, np.uint8, offset=HEADER_BYTES).reshape(
            self.n_samples, self.n_beams
        )
        platform_keys = ("Heading", "Pitch", "Roll", "Depth")
        platform = {k2.lower(): float(h[k2]) for k2 in platform_keys}
        angles = self.table.beam_angles_deg
        assert angles is not None  # every ARIS preset has its table
        return ArisFrame(
            index=int(k),
            image=image,
            ranges_m=ranges,
            angles_rad=np.deg2rad(angles),
            sound_speed_mps=c,
            heading_deg=float(h["CompassHeading"]),
            pitch_deg=float(h["CompassPitch"]),
            roll_deg=float(h["CompassRoll"]),
            platform=platform if any(platform.values()) else None,
        )

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        if ARIS_TOPIC not in topics:
            return
        wanted = None if times is None else set(times)
        for k in self._order.tolist():
            t = int(self._frame_times[k])
            if wanted is None or t in wanted:
                yield ARIS_TOPIC, t, self.frame(k)

    def attachments(self) -> dict[str, bytes]:
        return {}
