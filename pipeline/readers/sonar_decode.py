"""Sonar message -> `SonarPing` decoders, one per supported message type.

Every decoder returns the project's polar convention: rows = range bins near -> far
(`ranges_m` = bin centres), columns = beams with `angles_rad` ascending and positive to
the sensor's left (bearing for the horizontal sonar, elevation for the vertical one).
Oculus bearings are positive to starboard, so Oculus images are mirrored left-right.
A polar `sensor_msgs` image takes its beam angles from the sonar's configured preset or
table file (`keyframes.<role>_sonar`), else even spacing over `image_fov_deg`.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.projected_cdr import ProjectedArrays
from sonarmap.pipeline.readers.geometry_checks import beam_direction_problem, ping_problem
from sonarmap.pipeline.readers.limits import MAX_IMAGE_PIXELS
from sonarmap.pipeline.readers.sonar_models import SonarModel, even_beam_angles, load_sonar
from sonarmap.schemas.sonar import SonarPing, beam_angles_from_directions

__all__ = [
    "IMAGE_SONAR_TYPES",
    "SONAR_TYPES",
    "beam_directions",
    "configured_sonar",
    "decode_image",
    "decode_sonar",
    "fits_ping",
    "oculus_arrays",
    "sonar_descriptions",
]

PROJECTED = "marine_acoustic_msgs/msg/ProjectedSonarImage"
OCULUS = "sonar_oculus/msg/OculusPing"
OCULUS_RAW_MSG = "sonar_oculus/msg/OculusPingUncompressed"
OCULUS_FILE = "oculus/SimplePingResult"
ARIS = "aris/Frame"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"

SONAR_TYPES: tuple[str, ...] = (PROJECTED, OCULUS, OCULUS_RAW_MSG, OCULUS_FILE, ARIS)
"""Types recognised as sonar automatically."""
IMAGE_SONAR_TYPES: tuple[str, ...] = (IMAGE, COMPRESSED)
"""Polar images accepted as sonar only when a topic is configured (beam table from config)."""

_IMAGE_DTYPES = {
    "mono8": np.uint8,
    "8UC1": np.uint8,
    "mono16": np.uint16,
    "16UC1": np.uint16,
    "32FC1": np.float32,
    "64FC1": np.float64,
}
_COLOUR_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}
"""Colour encodings read when the image is grey (equal colour channels)."""
_ENCODINGS = ", ".join([*_IMAGE_DTYPES, *(f"grey {e}" for e in _COLOUR_CHANNELS)])
_PIL_MODES = {"L": np.uint8, "I;16": np.uint16, "I;16B": np.uint16, "I;16L": np.uint16}


def _grey(pixels: np.ndarray, what: str) -> np.ndarray:
    """(h, w, c) colour pixels -> (h, w) grey, when the image is grey stored in colour.

    A false-colour image (a colour map applied to the echoes) is refused: its grey level
    is no echo intensity, and a colour map cannot be read back without knowing it.
    """
    rgb = pixels[..., :3]
    if np.any(rgb != rgb[..., :1]):
        raise ValueError(
            f"{what} image in false colour (its colour channels differ): the echo"
            " intensities cannot be read back from a colour map; record the sonar's mono8"
            " or mono16 image"
        )
    return np.ascontiguousarray(rgb[..., 0])


def _decode_compressed(data: bytes) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            # The header's size is checked before any pixel is decoded.
            width, height = im.size
            if width * height > MAX_IMAGE_PIXELS:
                raise ValueError(
                    f"compressed image declares {width} x {height} pixels, over the "
                    f"limit of {MAX_IMAGE_PIXELS}"
                )
            mode = im.mode
            if mode in _PIL_MODES:
                return np.asarray(im).astype(_PIL_MODES[mode])
            if mode in ("RGB", "RGBA", "P", "LA", "1"):
                return _grey(np.asarray(im.convert("RGB")), f"compressed {mode}")
            raise ValueError(
                f"compressed image of mode {mode!r} (read: {', '.join(_PIL_MODES)}, RGB)"
            )
    except Image.DecompressionBombError as err:
        raise ValueError(f"compressed image too large ({err})") from err


def decode_image(msg: Any) -> np.ndarray:
    """sensor_msgs Image or CompressedImage -> (h, w) array of the encoding's type
    (uint8, uint16 or float); a grey image stored in colour -> its grey level.

    Raises:
        ValueError: the image is larger than `MAX_IMAGE_PIXELS`, its buffer does not hold
            the size it declares, its encoding is none of `_ENCODINGS`, it is in false
            colour, or a compressed image does not decode.
    """
    if hasattr(msg, "format"):
        return _decode_compressed(bytes(msg.data))
    encoding = str(msg.encoding)
    channels = _COLOUR_CHANNELS.get(encoding, 1)
    if channels == 1 and encoding not in _IMAGE_DTYPES:
        raise ValueError(f"image encoding {encoding[:20]!r}: sonarmap reads {_ENCODINGS}")
    dtype = np.dtype(_IMAGE_DTYPES.get(encoding, np.uint8))
    dtype = dtype.newbyteorder(">" if msg.is_bigendian else "<")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    n_bytes = len(msg.data)
    if height * width > MAX_IMAGE_PIXELS:
        raise ValueError(f"image declares {width} x {height} pixels, over the limit")
    width_bytes = width * channels * dtype.itemsize
    if step < width_bytes or height * step != n_bytes:
        raise ValueError(
            f"image declares {height} rows of {step} bytes ({width} pixels of "
            f"{encoding[:20]!r}) but holds {n_bytes} bytes"
        )
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(height, step)
    pixels = rows[:, :width_bytes].copy().view(dtype).astype(dtype.newbyteorder("="))
    if channels > 1:
        return _grey(pixels.reshape(height, width, channels), encoding)
    return pixels.reshape(height, width)


def _to_uint8(image: np.ndarray, bits: int | None = None) -> np.ndarray:
    """Echo intensities -> uint8: integers from their `bits` significant bits (None: the
    whole type), floats from 0..1.

    Raises:
        ValueError: pixels the conversion would lose: a 16-bit image whose pixels all lie
            under the 8 bits kept (written with fewer bits), values over `bits`, floats
            not finite or outside 0..1.
    """
    if image.dtype == np.uint8:
        return image
    if np.issubdtype(image.dtype, np.integer):
        width = 8 * image.dtype.itemsize
        bits = width if bits is None else min(bits, width)
        shift = max(0, bits - 8)
        top = int(image.max(initial=0))
        if top >> bits:
            raise ValueError(f"{width}-bit pixels up to {top}, over keyframes.image_bits = {bits}")
        if shift and top and not top >> shift:
            raise ValueError(
                f"every pixel of the {width}-bit image is under {1 << shift} (max {top}), so"
                f" none survives keeping its top 8 of {bits} bits: if the sonar writes"
                f" {top.bit_length()}-bit pixels, set keyframes.image_bits={max(8, top.bit_length())}"
            )
        return (image.astype(np.uint64) >> shift).astype(np.uint8)
    finite = np.isfinite(image)
    low = float(image.min(initial=0.0, where=finite))
    high = float(image.max(initial=0.0, where=finite))
    if not finite.all() or low < 0.0 or high > 1.0:
        bad = int(image.size - np.count_nonzero(finite))
        odd = f"{bad} of {image.size} pixels not finite, " if bad else ""
        raise ValueError(
            f"float image with {odd}values from {low:.4g} to {high:.4g}: sonarmap reads a"
            " float image as intensities in 0..1 (not dB, not 0..255)"
        )
    return (image * 255.0).astype(np.uint8)


def _ping(
    t_ns: int,
    sonar: str,
    image: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    bits: int | None = None,
    ping_info: tuple[float, float] = (0.0, 0.0),
) -> SonarPing:
    problem = ping_problem(image.shape, ranges, angles)
    if problem is not None:
        raise ValueError(problem)
    order = np.argsort(angles, kind="stable")
    if np.any(order != np.arange(len(order))):
        image, angles = image[:, order], angles[order]
    # ping_info as stated; 0 where it is no finite positive number (not stated)
    info = [float(v) if np.isfinite(v) and v > 0 else 0.0 for v in ping_info]
    return SonarPing(
        t_ns=int(t_ns),
        sonar=sonar,
        image=np.ascontiguousarray(_to_uint8(image, bits)),
        ranges_m=np.asarray(ranges, np.float32),
        angles_rad=np.asarray(angles, np.float32),
        frequency_hz=info[0],
        sound_speed_m_s=info[1],
    )


def oculus_arrays(
    image: np.ndarray, bearings_cdeg: np.ndarray, range_resolution_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Oculus polar image -> (image, ranges_m, angles_rad) in the project convention.

    Row k covers [k, k + 1) * range_resolution_m (row 0 starts at the transducer); its
    centre is returned. Bearings (0.01 deg, positive starboard) become angles positive
    left, and the columns are mirrored so the angles ascend.
    """
    n_r = image.shape[0]
    ranges = (np.arange(n_r) + 0.5) * range_resolution_m
    angles = -np.asarray(bearings_cdeg, np.float64)[::-1] * np.pi / 18000.0
    return image[:, ::-1], ranges, angles


def beam_directions(msg: Any) -> np.ndarray:
    """(n, 3) beam vectors of a ProjectedSonarImage (parsed arrays or rosbags object)."""
    if isinstance(msg, ProjectedArrays):
        return msg.directions
    return np.array([(v.x, v.y, v.z) for v in msg.beam_directions], np.float64).reshape(-1, 3)


def _projected(msg: Any, t_ns: int, sonar: str, _: Any) -> SonarPing:
    dirs = beam_directions(msg)
    if isinstance(msg, ProjectedArrays):
        ranges, n_b, data = msg.ranges, len(dirs), msg.data
        info = (msg.frequency_hz, msg.sound_speed_m_s)
    else:
        info = (msg.ping_info.frequency, msg.ping_info.sound_speed)
        ranges = np.asarray(msg.ranges, np.float32)
        n_b = int(msg.image.beam_count)
        if msg.image.dtype != 0:
            raise ValueError(f"ProjectedSonarImage dtype {msg.image.dtype} (only DTYPE_UINT8 = 0)")
        data = np.frombuffer(bytes(msg.image.data), np.uint8)
    if n_b != len(dirs) or data.size != len(ranges) * n_b:
        raise ValueError(
            f"ProjectedSonarImage with {len(dirs)} beam directions, beam_count {n_b}, "
            f"{len(ranges)} ranges and {data.size} bytes"
        )
    problem = beam_direction_problem(dirs)
    if problem is not None:
        raise ValueError(problem)
    angles = beam_angles_from_directions(dirs)
    return _ping(t_ns, sonar, data.reshape(len(ranges), n_b), ranges, angles, ping_info=info)


def _oculus(msg: Any, t_ns: int, sonar: str, options: Any) -> SonarPing:
    image = decode_image(msg.ping)
    n_r, n_b = int(msg.num_ranges), int(msg.num_beams)
    if image.shape != (n_r, n_b) or len(msg.bearings) != n_b:
        raise ValueError(
            f"OculusPing image {image.shape} != (num_ranges {n_r}, num_beams {n_b}) "
            f"or {len(msg.bearings)} bearings"
        )
    arrays = oculus_arrays(image, msg.bearings, float(msg.range_resolution))
    return _ping(t_ns, sonar, *arrays, getattr(options, "image_bits", None))


def _oculus_file(msg: Any, t_ns: int, sonar: str, options: Any) -> SonarPing:
    arrays = oculus_arrays(msg.image, msg.bearings_cdeg, msg.range_resolution_m)
    bits = getattr(options, "image_bits", None) or msg.sample_bits
    return _ping(t_ns, sonar, *arrays, bits, (msg.frequency_hz, msg.sound_speed_m_s))


def configured_sonar(options: Any, sonar: str) -> SonarModel | None:
    """The preset or beam-table file configured for a sonar role (`<role>_sonar`), if any."""
    spec = getattr(options, f"{sonar}_sonar", None)
    return load_sonar(str(spec)) if spec else None


def _table_angles(model: SonarModel | None, n_beams: int) -> np.ndarray | None:
    """The configured beam table [rad] in column order, None when it has none."""
    if model is None or model.beam_angles_deg is None:
        return None
    if len(model.beam_angles_deg) != n_beams:
        raise ValueError(
            f"the image has {n_beams} beams but the beam table of {model.source} has "
            f"{len(model.beam_angles_deg)} angles"
        )
    return np.deg2rad(model.beam_angles_deg)


def _polar_image(msg: Any, t_ns: int, sonar: str, options: Any) -> SonarPing:
    image = decode_image(msg)
    n_r, n_b = image.shape
    model = configured_sonar(options, sonar)
    angles = _table_angles(model, n_b)
    if angles is None:
        # column 0 = port (left), as Oculus images
        angles = even_beam_angles(model.fov_deg if model else options.image_fov_deg, n_b)
    max_range = getattr(options, f"{sonar}_image_max_range_m", None) or options.image_max_range_m
    ranges = (np.arange(n_r) + 0.5) * (max_range / n_r)
    return _ping(t_ns, sonar, image, ranges, angles, getattr(options, "image_bits", None))


def sonar_descriptions(
    options: Any, sonar_topics: dict[str, str], msgtypes: dict[str, str], source: Any
) -> dict[str, dict[str, Any]]:
    """Per sonar role, the geometry the messages do not carry: where the beam table comes
    from and, from a preset or table file, fan, vertical aperture and datasheet range.

    `fov_deg` is given only where it is not read from the messages' own beam table
    (polar images; ARIS frames, whose table is the maker's preset with its beam edges).
    """
    out: dict[str, dict[str, Any]] = {}
    for s, topic in sonar_topics.items():
        msgtype = msgtypes.get(topic, "")
        model = configured_sonar(options, s)
        if model is None and msgtype == ARIS:
            model = getattr(source, "table", None)
        entry: dict[str, Any] = {"beam_table": "message"}
        if model is not None:
            entry.update(model.summary())
            entry["beam_table"] = model.source if model.beam_angles_deg is not None else "message"
            if model.vertical_aperture_deg is not None:
                entry["vertical_aperture_deg"] = model.vertical_aperture_deg
            if model.max_range_m is not None:
                entry["datasheet_max_range_m"] = model.max_range_m
        if msgtype in IMAGE_SONAR_TYPES or msgtype == ARIS:
            entry["fov_deg"] = float(model.fov_deg if model else options.image_fov_deg)
            if model is None or model.beam_angles_deg is None:
                entry["beam_table"] = "even spacing"
        out[s] = entry
    return out


def _aris(msg: Any, t_ns: int, sonar: str, options: Any) -> SonarPing:
    angles = _table_angles(configured_sonar(options, sonar), len(msg.angles_rad))
    angles = msg.angles_rad if angles is None else angles
    return _ping(t_ns, sonar, msg.image, msg.ranges_m, angles, ping_info=(0.0, msg.sound_speed_mps))


_DECODERS: dict[str, Callable[[Any, int, str, Any], SonarPing]] = {
    PROJECTED: _projected,
    OCULUS: _oculus,
    OCULUS_RAW_MSG: _oculus,
    OCULUS_FILE: _oculus_file,
    ARIS: _aris,
    IMAGE: _polar_image,
    COMPRESSED: _polar_image,
}


def decode_sonar(
    msg: Any, msgtype: str, t_ns: int, sonar: str, options: Any, where: str
) -> SonarPing:
    """Decode one sonar message of any supported type.

    Args:
        msg: deserialised message.
        msgtype: its type name.
        t_ns: ping time [ns].
        sonar: "horizontal" or "vertical".
        options: reader options (`<sonar>_sonar`, `image_fov_deg`, `image_max_range_m`,
            `<sonar>_image_max_range_m` for polar images and beam tables).
        where: "file topic" for error messages.

    Raises:
        SourceError: unsupported type or inconsistent message.
    """
    decoder = _DECODERS.get(msgtype)
    if decoder is None:
        raise SourceError(
            f"{where}: type {msgtype} is not a supported sonar type {sorted(_DECODERS)}"
        )
    try:
        return decoder(msg, t_ns, sonar, options)
    except (ValueError, OSError) as err:
        raise SourceError(f"{where}: bad {msgtype} message at t_ns={t_ns} ({err})") from err


def label_column_order(
    msg: Any, msgtype: str, sonar: str, options: Any, n_beams: int
) -> np.ndarray:
    """The column permutation `decode_sonar` applied to a ping of `n_beams` beams (to apply
    to its label and truth images)."""
    model = configured_sonar(options, sonar) if msgtype in IMAGE_SONAR_TYPES else None
    if model is not None and model.beam_angles_deg is not None:
        return np.argsort(model.beam_angles_deg, kind="stable")
    if msgtype.endswith("ProjectedSonarImage"):
        return np.argsort(beam_angles_from_directions(beam_directions(msg)), kind="stable")
    # Polar images and Oculus pings: column 0 is port, mirrored (a compressed image's
    # width is known only once decoded, hence the decoded ping's beam count).
    return np.arange(n_beams)[::-1]


def fits_ping(image: np.ndarray, ping_image: np.ndarray) -> np.ndarray:
    """`image` (a ping's label or truth image), checked to have the ping's shape.

    Raises:
        ValueError: another shape (its pixels would be read against the wrong cells).
    """
    if image.shape != ping_image.shape:
        raise ValueError(f"a {image.shape} image beside a ping of {ping_image.shape}")
    return image
