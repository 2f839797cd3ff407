"""ProjectedSonarImage <-> little-endian CDR, straight from and to numpy arrays.

The `marine_acoustic_msgs/msg/ProjectedSonarImage` wire format, byte-identical to rosbags'
serde without a Python object per beam: the readers parse recordings' pings with it
(`sonarmap.pipeline.readers.sonar_decode`), the `frames` codec and the simulator write
theirs (`sonarmap.pipeline.formats.frames_io`). A format, so it sits below the readers.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

__all__ = ["ProjectedArrays", "parse_projected_cdr", "serialize_projected_cdr"]


@dataclass(frozen=True)
class ProjectedArrays:
    """A ProjectedSonarImage parsed straight from CDR (see `parse_projected_cdr`).

    Attributes:
        stamp_ns: header stamp [ns]; frame_id: header frame.
        directions: (n_beams, 3) beam unit vectors; ranges: (n_ranges,) float32 [m];
        data: (n_ranges * n_beams,) uint8 range-major image.
        frequency_hz, sound_speed_m_s: `ping_info`'s (0: not stated).
    """

    stamp_ns: int
    frame_id: str
    directions: np.ndarray
    ranges: np.ndarray
    data: np.ndarray
    frequency_hz: float = 0.0
    sound_speed_m_s: float = 0.0

    @classmethod
    def from_cdr(cls, data: bytes | memoryview) -> ProjectedArrays:
        return cls(*parse_projected_cdr(data))


def _align(pos: int, size: int) -> int:
    """CDR alignment: offsets count from the end of the 4-byte encapsulation header."""
    return pos + (-(pos - 4)) % size


def parse_projected_cdr(
    data: bytes | memoryview,
) -> tuple[int, str, np.ndarray, np.ndarray, np.ndarray]:
    """Fast little-endian CDR parse of a ProjectedSonarImage (no per-beam Python objects).

    Returns:
        (stamp t_ns, frame_id, (n_beams, 3) float64 beam directions, (n_ranges,) float32
        ranges, (n_ranges * n_beams,) uint8 image data, ping_info's frequency [Hz] and
        sound speed [m/s]). Raises ValueError when the payload is not little-endian CDR
        or is inconsistent.
    """
    buf = memoryview(data)
    if bytes(buf[:2]) != b"\x00\x01":
        raise ValueError("not little-endian CDR")
    u32 = np.dtype("<u4")
    sec, nsec, n = struct.unpack_from("<iII", buf, 4)
    frame_id = bytes(buf[16 : 16 + n - 1]).decode()
    pos = _align(16 + n, 4)
    frequency, sound_speed = np.frombuffer(buf, "<f4", 2, pos).tolist()
    pos += 8
    for _ in range(2):  # tx_beamwidths, rx_beamwidths
        pos = _align(pos, 4)
        pos += 4 + 4 * int(np.frombuffer(buf, u32, 1, pos)[0])
    pos = _align(pos, 4)
    n_beams = int(np.frombuffer(buf, u32, 1, pos)[0])
    pos = _align(pos + 4, 8) if n_beams else pos + 4
    dirs = np.frombuffer(buf, "<f8", 3 * n_beams, pos).reshape(n_beams, 3)
    pos = _align(pos + 24 * n_beams, 4)
    n_ranges = int(np.frombuffer(buf, u32, 1, pos)[0])
    ranges = np.frombuffer(buf, "<f4", n_ranges, pos + 4)
    pos += 4 + 4 * n_ranges + 1  # is_bigendian
    pos = _align(pos, 4)
    dtype, beam_count, n_data = np.frombuffer(buf, u32, 3, pos).tolist()
    if dtype != 0 or beam_count != n_beams or n_data != n_ranges * n_beams:
        raise ValueError(
            f"ProjectedSonarImage dtype {dtype}, beam_count {beam_count}, {n_beams} beam "
            f"directions, {n_ranges} ranges, {n_data} bytes"
        )
    image = np.frombuffer(buf, np.uint8, n_data, pos + 12)
    return sec * 1_000_000_000 + nsec, frame_id, dirs, ranges, image, frequency, sound_speed


def serialize_projected_cdr(
    stamp_ns: int,
    frame_id: str,
    directions: np.ndarray,
    ranges_m: np.ndarray,
    image: np.ndarray,
    ping_info: tuple[float, float] = (0.0, 0.0),
) -> bytes:
    """Little-endian CDR of a ProjectedSonarImage (ping_info's frequency [Hz] and sound speed
    [m/s], no beamwidths; uint8 range-major image); byte-identical to rosbags'
    `serialize_cdr` of the same message, without per-beam objects."""
    out = bytearray(b"\x00\x01\x00\x00")

    def pad(size: int) -> None:
        out.extend(b"\x00" * ((-(len(out) - 4)) % size))

    name = frame_id.encode() + b"\x00"
    out += np.array([stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000], "<u4").tobytes()
    out += np.uint32(len(name)).tobytes() + name
    pad(4)
    out += np.array(ping_info, "<f4").tobytes() + np.zeros(2, "<u4").tobytes()  # 0 tx, 0 rx
    dirs = np.ascontiguousarray(directions, "<f8").reshape(-1, 3)
    out += np.uint32(len(dirs)).tobytes()
    if len(dirs):
        pad(8)
        out += dirs.tobytes()
    pad(4)
    r = np.ascontiguousarray(ranges_m, "<f4")
    out += np.uint32(len(r)).tobytes() + r.tobytes()
    out += b"\x00"  # is_bigendian
    pad(4)
    data = np.ascontiguousarray(image, np.uint8)
    out += np.array([0, data.shape[1], data.size], "<u4").tobytes() + data.tobytes()
    return bytes(out)
