"""Raw Oculus network captures: concatenated `SimplePingResult` messages.

Layout (Blueprint Subsea protocol, little-endian, packed; liboculus `Oculus.h`):
a 16-byte `OculusMessageHeader` (oculusId 0x4f53, srcDeviceId, dstDeviceId, msgId,
msgVersion, payloadSize u32, spare), the `OculusSimpleFireMessage` body (masterMode,
pingRate, networkSpeed, gammaCorrection, flags: u8; range, gainPercent, speedOfSound,
salinity: f64), then pingId, status (u32), frequency, temperature, pressure,
speedOfSoundUsed (f64), pingStartTime (u32), dataSize (u8), rangeResolution (f64),
nRanges, nBeams (u16), imageOffset, imageSize, messageSize (u32), then nBeams int16
bearings [0.01 deg] at byte 122 and the image at `imageOffset`: nRanges rows of nBeams
samples, each row preceded by a u32 gain when flag bit 2 (send gain) is set.

A capture is read one message at a time (opened through the guarded reader, each message
capped at `max_chunk_bytes`), never whole: memory stays one ping whatever its size, and a
header claiming more than the file holds is found from the file's size, not by reading.
"""

from __future__ import annotations

import os
from array import array
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.engine.user_files import open_user_file
from sonarmap.pipeline.readers.limits import CHUNK_LIMIT_ENV, max_chunk_bytes
from sonarmap.pipeline.readers.source_types import TopicInfo

__all__ = ["OCULUS_RAW_TOPIC", "OCULUS_RAW_TYPE", "OculusRawPing", "OculusRawSource", "parse_ping"]

OCULUS_RAW_TOPIC = "/oculus/ping"
OCULUS_RAW_TYPE = "oculus/SimplePingResult"
_HEADER = np.dtype(
    [
        ("oculus_id", "<u2"),
        ("src", "<u2"),
        ("dst", "<u2"),
        ("msg_id", "<u2"),
        ("version", "<u2"),
        ("payload_size", "<u4"),
        ("spare", "<u2"),
    ]
)
_PING = np.dtype(
    [
        ("head", _HEADER),
        ("master_mode", "u1"),
        ("ping_rate", "u1"),
        ("network_speed", "u1"),
        ("gamma", "u1"),
        ("flags", "u1"),
        ("range", "<f8"),
        ("gain_percent", "<f8"),
        ("speed_of_sound", "<f8"),
        ("salinity", "<f8"),
        ("ping_id", "<u4"),
        ("status", "<u4"),
        ("frequency", "<f8"),
        ("temperature", "<f8"),
        ("pressure", "<f8"),
        ("speed_of_sound_used", "<f8"),
        ("ping_start_time", "<u4"),
        ("data_size", "u1"),
        ("range_resolution", "<f8"),
        ("n_ranges", "<u2"),
        ("n_beams", "<u2"),
        ("image_offset", "<u4"),
        ("image_size", "<u4"),
        ("message_size", "<u4"),
    ]
)
_OCULUS_ID = 0x4F53
_SIMPLE_PING_RESULT = 0x23
_SAMPLE_BYTES = {0: 1, 1: 2, 2: 3, 3: 4}
"""Bytes of a sample by `dataSize` (liboculus `DataSizeType`: 8, 16, 24, 32 bit)."""


class NotAPing(ValueError):
    """The bytes are not a SimplePingResult at all (another message, another format)."""


def _samples(rows: np.ndarray, n_beams: int, size: int) -> np.ndarray:
    """(n_ranges, n_beams) little-endian unsigned samples of `size` bytes from (n_ranges,
    n_beams * size) bytes; 24-bit samples widened to 32 bits."""
    if size == 3:
        b = rows.reshape(len(rows), n_beams, 3).astype(np.uint32)
        return b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    dtype = np.dtype({1: "u1", 2: "<u2", 4: "<u4"}[size])
    return np.ascontiguousarray(rows).view(dtype).reshape(len(rows), n_beams)


@dataclass(frozen=True)
class OculusRawPing:
    """One decoded SimplePingResult (Oculus conventions: bearings positive to starboard).

    Attributes:
        ping_id: sonar ping counter.
        image: (n_ranges, n_beams) samples, rows near -> far, columns port -> starboard.
        bearings_cdeg: (n_beams,) int16 bearings [0.01 deg], ascending.
        range_resolution_m: bin length [m].
        frequency_hz: operating frequency [Hz].
        sound_speed_m_s: the sound speed the ranges were computed with [m/s].
        sample_bits: bits of a sample as sent (8, 16, 24 or 32; 24 widened to 32).
    """

    ping_id: int
    image: np.ndarray
    bearings_cdeg: np.ndarray
    range_resolution_m: float
    frequency_hz: float
    sound_speed_m_s: float = 0.0
    sample_bits: int = 8


def parse_ping(buf: bytes, offset: int = 0, at: int = 0) -> tuple[OculusRawPing, int]:
    """Decode the SimplePingResult at `offset`; returns it and the offset after it. `at`
    is where `buf` starts in its file (for the byte offsets in messages).

    Raises:
        NotAPing: not a SimplePingResult.
        ValueError: a SimplePingResult (v1) cut short or with a field that does not fit.
    """
    where = f"ping at byte {at + offset}"
    if len(buf) - offset < _PING.itemsize:
        raise NotAPing(f"{len(buf) - offset} bytes left, a ping header needs {_PING.itemsize}")
    h = np.frombuffer(buf, _PING, 1, offset)[0]
    head = h["head"]
    if head["oculus_id"] != _OCULUS_ID or head["msg_id"] != _SIMPLE_PING_RESULT:
        raise NotAPing(
            f"message id {int(head['msg_id']):#x} at byte {at + offset} is not SimplePingResult"
        )
    if head["version"] == 2:
        raise NotAPing("SimplePingResult2 (msgVersion 2) is not supported")
    end = offset + 16 + int(head["payload_size"])
    n_r, n_b = int(h["n_ranges"]), int(h["n_beams"])
    if end > len(buf):
        raise ValueError(f"{where} is cut short ({len(buf) - offset} of {end - offset} bytes)")
    size = _SAMPLE_BYTES.get(int(h["data_size"]))
    if size is None:
        raise ValueError(f"{where}: dataSize {int(h['data_size'])} is none of 0-3 (8-32 bit)")
    gain = 4 if int(h["flags"]) & 0x04 else 0
    stride = n_b * size + gain
    bearings_end = _PING.itemsize + 2 * n_b
    image_offset = int(h["image_offset"])
    if image_offset < bearings_end:
        raise ValueError(
            f"{where}: imageOffset {image_offset} points inside the header and the"
            f" nBeams {n_b} bearings (they end at byte {bearings_end})"
        )
    if int(h["image_size"]) < n_r * stride or image_offset + n_r * stride > end - offset:
        raise ValueError(
            f"{where}: nRanges {n_r} x nBeams {n_b} x {size} bytes"
            + (" + a 4-byte gain per row" if gain else "")
            + f" = {n_r * stride} bytes, more than imageSize {int(h['image_size'])} or the"
            f" {end - offset - image_offset} bytes after imageOffset"
        )
    start = offset + image_offset
    rows = np.frombuffer(buf, np.uint8, n_r * stride, start).reshape(n_r, stride)
    image = _samples(rows[:, gain:], n_b, size)
    bearings = np.frombuffer(buf, "<i2", n_b, offset + _PING.itemsize).astype(np.int16)
    ping = OculusRawPing(
        ping_id=int(h["ping_id"]),
        image=image,
        bearings_cdeg=bearings,
        range_resolution_m=float(h["range_resolution"]),
        frequency_hz=float(h["frequency"]),
        sound_speed_m_s=float(h["speed_of_sound_used"]),
        sample_bits=8 * size,
    )
    return ping, end


class OculusRawSource:
    """A file of concatenated SimplePingResult messages: one sonar topic.

    Captures carry no wall-clock stamp per message; ping k gets t_ns = k * 1e8 (10 Hz),
    enough to order pings (there is no navigation in such a file).
    """

    kind = "oculus-raw"
    period_ns = 100_000_000

    def __init__(self, path: Path) -> None:
        self.path = path
        self.warnings: list[str] = []
        # Start and size of each message (8 bytes a ping, not a list of Python ints).
        self._offsets, self._sizes = array("q"), array("q")
        with open_user_file(path, "raw Oculus capture", SourceError) as f:
            size = os.fstat(f.fileno()).st_size
            pos = 0
            while pos < size:
                try:
                    n = self._message(f, pos, size)
                except NotAPing as err:
                    if not self._offsets:
                        raise SourceError(f"{path}: not a raw Oculus capture ({err})") from err
                    self.warnings.append(f"{path}: {size - pos} trailing bytes unreadable ({err})")
                    break
                except ValueError as err:
                    if not self._offsets:
                        raise SourceError(f"{path}: {err}") from err
                    self.warnings.append(f"{path}: {size - pos} trailing bytes unreadable ({err})")
                    break
                self._offsets.append(pos)
                self._sizes.append(n)
                pos += n
        # Each ping's pingStartTime counts from the sonar's power-up, not a clock.
        self.warnings.append(
            f"{path}: a raw capture stamps no ping with a clock: its pings are placed"
            f" {self.period_ns / 1e9:g} s apart from t = 0 (1970)"
        )

    @staticmethod
    def _message(f: Any, pos: int, size: int) -> int:
        """The size of the message at `pos`, checked by decoding it (ValueError if it is
        not a ping, is cut short, or is over the cap)."""
        f.seek(pos)
        head = f.read(_PING.itemsize)
        if len(head) < _PING.itemsize:
            raise ValueError(f"{len(head)} bytes left, a ping header needs {_PING.itemsize}")
        n = 16 + int(np.frombuffer(head, _HEADER, 1)[0]["payload_size"])
        limit = max_chunk_bytes()
        if n > limit:
            raise ValueError(
                f"ping at byte {pos} declares {n} bytes, over the limit of {limit >> 20} MiB "
                f"(set {CHUNK_LIMIT_ENV} to raise it)"
            )
        # A claim past the end of the file is cut short without reading up to it.
        n = min(n, size - pos)
        parse_ping(head + f.read(n - len(head)) if n > len(head) else head, at=pos)
        return n

    def topics(self) -> list[TopicInfo]:
        n = len(self._offsets)
        return [TopicInfo(OCULUS_RAW_TOPIC, OCULUS_RAW_TYPE, n, 0, (n - 1) * self.period_ns, n)]

    def times(self, topic: str) -> np.ndarray:
        if topic != OCULUS_RAW_TOPIC:
            return np.zeros(0, np.int64)
        return np.arange(len(self._offsets), dtype=np.int64) * self.period_ns

    def messages(
        self, topics: Sequence[str], times: Collection[int] | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        if OCULUS_RAW_TOPIC not in topics:
            return
        wanted = None if times is None else set(times)
        with open_user_file(self.path, "raw Oculus capture", SourceError) as f:
            for k, (off, n) in enumerate(zip(self._offsets, self._sizes, strict=True)):
                t = k * self.period_ns
                if wanted is None or t in wanted:
                    f.seek(off)
                    try:
                        ping = parse_ping(f.read(n), at=off)[0]
                    except ValueError as err:  # the file changed since it was opened
                        raise SourceError(f"{self.path}: ping {k}: {err}") from err
                    yield OCULUS_RAW_TOPIC, t, ping

    def attachments(self) -> dict[str, bytes]:
        return {}
