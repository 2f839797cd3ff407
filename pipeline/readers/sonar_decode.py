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


def decode_image(msg: Any) -> np.ndarray:
    """sensor_msgs Image (single channel) or CompressedImage -> (h, w) array.

    Raises:
        ValueError: the image is larger than `MAX_IMAGE_PIXELS`, its buffer does not hold
            the size it declares, or a compressed image does not decode.
    """
    if hasattr(msg, "format"):
        from PIL import Image

        try:
            with Image.open(io.BytesIO(bytes(msg.data))) as im:
                # The header's size is checked before any pixel is decoded.
                width, height = im.size
                if width * height > MAX_IMAGE_PIXELS:
                    raise ValueError(
                        f"compressed image declares {width} x {height} pixels, over the "
                        f"limit of {MAX_IMAGE_PIXELS}"
                    )
                return np.asarray(im.convert("L"))
        except Image.DecompressionBombError as err:
            raise ValueError(f"compressed image too large ({err})") from err
    dtype = np.dtype(_IMAGE_DTYPES.get(msg.encoding, np.uint8))
    dtype = dtype.newbyteorder(">" if msg.is_bigendian else "<")
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    n_bytes = len(msg.data)
    if height * width > MAX_IMAGE_PIXELS:
        raise ValueError(f"image declares {width} x {height} pixels, over the limit")
    if step < width * dtype.itemsize or height * step != n_bytes:
        raise ValueError(
            f"image declares {height} rows of {step} bytes ({width} pixels of "
            f"{msg.encoding[:20]!r}) but holds {n_bytes} bytes"
        )
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(height, step)
    width_bytes = width * dtype.itemsize
    return (
        rows[:, :width_bytes]
        .copy()
        .view(dtype)
        .reshape(height, width)
        .astype(dtype.newbyteorder("="))
    )


def _to_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if np.issubdtype(image.dtype, np.integer):
        shift = 8 * (image.dtype.itemsize - 1)
        return (image.astype(np.uint64) >> shift).astype(np.uint8)
    return np.clip(image * 255.0, 0, 255).astype(np.uint8)


def _ping(
    t_ns: int, sonar: str, image: np.ndarray, ranges: np.ndarray, angles: np.ndarray
) -> SonarPing:
    problem = ping_problem(image.shape, ranges, angles)
    if problem is not None:
        raise ValueError(problem)
    order = np.argsort(angles, kind="stable")
    if np.any(order != np.arange(len(order))):
        image, angles = image[:, order], angles[order]
    return SonarPing(
        t_ns=int(t_ns),
        sonar=sonar,
        image=np.ascontiguousarray(_to_uint8(image)),
        ranges_m=np.asarray(ranges, np.float32),
        angles_rad=np.asarray(angles, np.float32),
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
    else:
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
    return _ping(
        t_ns, sonar, data.reshape(len(ranges), n_b), ranges, beam_angles_from_directions(dirs)
    )


def _oculus(msg: Any, t_ns: int, sonar: str, _: Any) -> SonarPing:
    image = decode_image(msg.ping)
    n_r, n_b = int(msg.num_ranges), int(msg.num_beams)
    if image.shape != (n_r, n_b) or len(msg.bearings) != n_b:
        raise ValueError(
            f"OculusPing image {image.shape} != (num_ranges {n_r}, num_beams {n_b}) "
            f"or {len(msg.bearings)} bearings"
        )
    return _ping(t_ns, sonar, *oculus_arrays(image, msg.bearings, float(msg.range_resolution)))


def _oculus_file(msg: Any, t_ns: int, sonar: str, _: Any) -> SonarPing:
    return _ping(t_ns, sonar, *oculus_arrays(msg.image, msg.bearings_cdeg, msg.range_resolution_m))


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
    return _ping(t_ns, sonar, image, ranges, angles)


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
    return _ping(t_ns, sonar, msg.image, msg.ranges_m, msg.angles_rad if angles is None else angles)


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


def label_column_order(msg: Any, msgtype: str, sonar: str, options: Any) -> np.ndarray:
    """The column permutation `decode_sonar` applied to a ping (to apply to its label and
    truth images)."""
    model = configured_sonar(options, sonar) if msgtype in IMAGE_SONAR_TYPES else None
    if model is not None and model.beam_angles_deg is not None:
        return np.argsort(model.beam_angles_deg, kind="stable")
    if msgtype.endswith("ProjectedSonarImage"):
        return np.argsort(beam_angles_from_directions(beam_directions(msg)), kind="stable")
    n = int(getattr(msg, "num_beams", 0) or getattr(msg, "width", 0))
    return np.arange(n)[::-1]
