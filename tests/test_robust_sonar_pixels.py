"""Campaign 4 (sonar pixels as drivers publish them): encodings, bit depths, float images
and beam tables that used to be read as something else and mapped metres off with exit 0.
Each is now read right or refused in one line naming what it is."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from sonarmap.pipeline.readers.geometry_checks import ping_problem
from sonarmap.pipeline.readers.sonar_decode import _to_uint8, decode_image

GREY = (np.arange(6 * 5, dtype=np.uint8) * 8).reshape(6, 5)


def _raw(pixels: np.ndarray, encoding: str) -> SimpleNamespace:
    h, w = pixels.shape[:2]
    data = pixels.tobytes()
    return SimpleNamespace(
        encoding=encoding, is_bigendian=0, height=h, width=w, step=len(data) // h, data=data
    )


def _png(pixels: np.ndarray) -> SimpleNamespace:
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, "PNG")
    return SimpleNamespace(format="png", data=out.getvalue())


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_a_grey_image_stored_in_colour_is_its_grey_level(encoding: str) -> None:
    # Was read as mono8 over the first third of each row: the map 4 m off, exit 0.
    colour = np.repeat(GREY[..., None], 3, axis=2)
    assert np.array_equal(decode_image(_raw(colour, encoding)), GREY)
    rgba = np.concatenate([colour, np.full((*GREY.shape, 1), 255, np.uint8)], axis=2)
    assert np.array_equal(decode_image(_raw(rgba, "rgba8")), GREY)
    assert np.array_equal(decode_image(_png(colour)), GREY)


def test_a_false_colour_image_is_refused_raw_or_compressed() -> None:
    colour = np.stack([GREY, GREY[::-1], GREY], axis=2)
    for msg in (_raw(colour, "bgr8"), _png(colour)):
        with pytest.raises(ValueError, match="false colour"):
            decode_image(msg)


@pytest.mark.parametrize("encoding", ["16SC1", "8SC1", "yuv422", "bayer_rggb8"])
def test_an_encoding_it_does_not_read_is_named(encoding: str) -> None:
    with pytest.raises(ValueError, match=f"image encoding '{encoding}': sonarmap reads mono8"):
        decode_image(_raw(np.zeros((4, 8), np.uint8), encoding))


def test_a_16_bit_png_keeps_its_16_bits() -> None:
    # Pillow's convert("L") clipped it to 255: "saturated", refused.
    wide = GREY.astype(np.uint16) * 256 + 7
    assert np.array_equal(_to_uint8(decode_image(_png(wide))), GREY)
    assert np.array_equal(_to_uint8(decode_image(_raw(wide, "mono16"))), GREY)


def test_16_bit_pixels_are_read_from_their_significant_bits() -> None:
    twelve = GREY.astype(np.uint16) * 16  # 12-bit pixels in a mono16 image
    assert np.array_equal(_to_uint8(twelve, 12), GREY)
    eight = GREY.astype(np.uint16)  # 8-bit pixels in a mono16 image: all gone at >> 8
    with pytest.raises(ValueError, match=r"set keyframes\.image_bits=8"):
        _to_uint8(eight)
    assert np.array_equal(_to_uint8(eight, 8), GREY)
    with pytest.raises(ValueError, match=r"up to 3712, over keyframes\.image_bits = 8"):
        _to_uint8(twelve, 8)
    assert not _to_uint8(np.zeros((3, 3), np.uint16)).any()  # a silent ping stays one


def test_a_float_image_must_hold_finite_intensities_in_0_to_1() -> None:
    assert np.array_equal(_to_uint8(GREY / 255.0), GREY)
    nan = GREY / 255.0
    nan[0, 0] = np.nan
    with pytest.raises(ValueError, match="1 of 30 pixels not finite"):
        _to_uint8(nan)
    with pytest.raises(ValueError, match=r"values from 0 to 232: .* \(not dB, not 0..255\)"):
        _to_uint8(GREY.astype(np.float32))
    with pytest.raises(ValueError, match="values from -40 to 0"):
        _to_uint8(np.linspace(-40.0, 0.0, 12).reshape(3, 4))


def test_beam_tables_in_no_order_or_spanning_no_fan_are_refused() -> None:
    ranges = np.linspace(0.5, 30.0, 8)
    fan = np.deg2rad(np.linspace(-65.0, 65.0, 16))
    assert ping_problem((8, 16), ranges, fan) is None
    assert ping_problem((8, 16), ranges, fan[::-1]) is None  # descending: mirrored, fine
    assert ping_problem((8, 16), ranges, np.round(fan, 2)) is None  # duplicates by rounding
    degrees_as_radians = np.sin(np.linspace(-65.0, 65.0, 16))
    assert "rise and fall" in str(ping_problem((8, 16), ranges, degrees_as_radians))
    assert "span 0 deg" in str(ping_problem((8, 16), ranges, np.zeros(16)))
    # A first bin edge at 0 m less float rounding is no negative range.
    assert ping_problem((8, 16), np.r_[-1.9e-9, ranges[1:]], fan) is None
    assert "negative range" in str(ping_problem((8, 16), np.r_[-0.01, ranges[1:]], fan))


def test_blank_and_saturated_pings_are_left_out_of_the_calibration() -> None:
    # A dive whose first pings are all 255 (in air) was refused as "saturated"; all 0 (not
    # yet pinging) set the thresholds low. They are now left out, with a warning.
    from sonarmap.schemas.sonar import KeyframeImages, SonarPing
    from sonarmap.stages.features.calibration import calibrate_sample
    from sonarmap.stages.features.config import FeaturesConfig

    rng = np.random.default_rng(0)
    ranges = np.linspace(0.5, 30.0, 200, dtype=np.float32)
    angles = np.deg2rad(np.linspace(-65.0, 65.0, 64)).astype(np.float32)

    def frame(t: int, image: np.ndarray) -> KeyframeImages:
        pings = [SonarPing(t, s, image, ranges, angles) for s in ("horizontal", "vertical")]
        return KeyframeImages(t, t, *pings)

    def speckle() -> np.ndarray:
        return np.clip(rng.weibull(1.2, (200, 64)) * 40.0, 0, 255).astype(np.uint8)

    good = [frame(t, speckle()) for t in range(10, 16)]
    air = [frame(t, np.full((200, 64), 255, np.uint8)) for t in range(4)]
    silent = [frame(t, np.zeros((200, 64), np.uint8)) for t in range(4, 6)]
    config = FeaturesConfig()
    clean = calibrate_sample(good, config)
    doc = calibrate_sample([*air, *silent, *good], config)
    assert doc["sonars"]["horizontal"]["bands"] == clean["sonars"]["horizontal"]["bands"]
    assert doc["sonars"]["horizontal"]["constant_t_ns"] == list(range(6))
    assert any(
        "horizontal sonar: 6 of 12 calibration pings hold one level in every pixel (0, 255)" in w
        for w in doc["warnings"]
    )
    with pytest.raises(Exception, match="no background to calibrate on"):
        calibrate_sample(air, config)


def test_a_gain_step_during_the_dive_is_warned_with_its_levels_and_times() -> None:
    # Gain x1.8 half-way: the map 2.4 m off, and the horizontal sonar, with no background
    # band to measure a rate on, said nothing.
    from sonarmap.stages.features.calibration import _level_change

    t = [int(k * 10e9) for k in range(8)]
    steady = [44.0, 43.0, 44.0, 45.0, 43.0, 44.0, 44.0, 43.0]
    assert _level_change(steady, t) == ""
    stepped = [*steady[:4], 78.0, 77.0, 79.0, 77.0]
    assert _level_change(stepped, t).startswith(
        "the sampled pings' median level runs from 43 (at 10 s) to 79 (at 60 s)"
    )
    assert _level_change([2.0, 4.0, 3.0], t[:3]) == ""  # dark images move by whole levels
