"""CFAR along range: threshold factors, fast path vs a reference loop, real and synthetic images."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.pipeline.readers.oculus_raw import parse_ping
from sonarmap.stages.kernels.cfar import cfar_detect, cfar_noise, threshold_factor

METHODS = ("soca", "ca", "go", "os")


@pytest.mark.parametrize(
    ("n_train", "pfa", "tau"),
    [(20, 0.2, 2.080), (20, 0.5, 0.864), (40, 0.1, 2.749), (10, 0.1, 3.711), (80, 0.2, 1.793)],
)
def test_soca_threshold_factor_matches_the_reference_table(
    n_train: int, pfa: float, tau: float
) -> None:
    assert threshold_factor("soca", n_train, pfa) == pytest.approx(tau, abs=1e-3)


def test_ca_threshold_factor_is_the_closed_form() -> None:
    assert threshold_factor("ca", 20, 0.1) == pytest.approx(20 * (0.1 ** (-1 / 20) - 1), rel=1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_false_alarm_rate_on_exponential_noise_matches_pfa(method: str) -> None:
    """The Pfa formulas hold for their model: square-law (exponential) white noise."""
    rng = np.random.default_rng(0)
    noise = rng.exponential(1.0, size=(2000, 300))
    pfa = 0.01
    det = cfar_detect(noise, train_hs=8, guard_hs=2, pfa=pfa, method=method)  # type: ignore[arg-type]
    rate = det[10:-10].mean()
    assert rate == pytest.approx(pfa, rel=0.08)


def _reference_noise(img: np.ndarray, th: int, gh: int, method: str, rank: int) -> np.ndarray:
    """Slow per-row loop of the section 2.1 detector."""
    f = img.astype(np.float64)
    out = np.full(f.shape, np.inf)
    for i in range(th + gh, f.shape[0] - th - gh):
        lead, lag = f[i - gh - th : i - gh], f[i + gh + 1 : i + gh + th + 1]
        if method == "soca":
            out[i] = np.minimum(lead.sum(0), lag.sum(0)) / th
        elif method == "go":
            out[i] = np.maximum(lead.sum(0), lag.sum(0)) / th
        elif method == "ca":
            out[i] = (lead.sum(0) + lag.sum(0)) / (2 * th)
        else:
            out[i] = np.sort(np.concatenate([lead, lag]), axis=0)[rank - 1]
    return out


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_vectorised_detector_equals_reference_loop(method: str, dtype: type) -> None:
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (120, 37)).astype(dtype)
    th, gh, pfa, floor = 6, 2, 0.1, 30.0
    rank = 4 if method == "os" else 0
    tau = threshold_factor(method, 2 * th, pfa, rank)  # type: ignore[arg-type]
    ref_noise = _reference_noise(img, th, gh, method, rank)
    np.testing.assert_allclose(cfar_noise(img, th, gh, method, rank), ref_noise)  # type: ignore[arg-type]
    expected = (img > tau * ref_noise) & (img > floor)
    got = cfar_detect(img, th, gh, pfa, method, rank, floor)  # type: ignore[arg-type]
    assert np.array_equal(got, expected)
    w = th + gh
    assert not got[:w].any() and not got[-w:].any()


def test_blobs_over_rayleigh_speckle_are_found_and_nothing_else() -> None:
    rng = np.random.default_rng(2)
    img = rng.rayleigh(4.0, size=(400, 128))
    truth = np.zeros(img.shape, dtype=bool)
    for r, b in [(60, 10), (150, 64), (300, 100), (350, 30)]:
        truth[r : r + 3, b : b + 4] = True
    img[truth] *= 0.0
    img[truth] += 120.0 * rng.rayleigh(np.sqrt(2 / np.pi), truth.sum())
    img8 = np.clip(img, 0, 255).astype(np.uint8)
    det = cfar_detect(img8, 10, 5, 0.1, "soca", floor=20.0)
    assert det[truth].mean() >= 0.9
    assert (det & ~truth).sum() <= 2


def test_bad_arguments_raise_value_error() -> None:
    with pytest.raises(ValueError, match="even"):
        threshold_factor("soca", 7, 0.1)
    with pytest.raises(ValueError, match="pfa"):
        threshold_factor("ca", 20, 1.5)
    with pytest.raises(ValueError, match="rank"):
        threshold_factor("os", 20, 0.1, 21)
    with pytest.raises(ValueError, match="unknown"):
        cfar_detect(np.zeros((50, 4)), 5, 2, 0.1, "max")  # type: ignore[arg-type]


def test_image_shorter_than_the_window_has_no_detections() -> None:
    assert not cfar_detect(np.full((10, 3), 200, np.uint8), 10, 5, 0.1).any()


def test_real_oculus_ping_gives_a_plausible_number_of_detections(shared_data: Path) -> None:
    """M1200d ping, 703 x 256, 2 m range: a bright seabed band around rows 250-420.

    Default setting (10 training + 5 guard per side, Pfa 0.1, floor 20): about 0.6 % of
    the cells, on the band and its leading edge, none in the near-field water.
    """
    path = shared_data / "oculus" / "one_ping_8bit.raw"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    image = parse_ping(path.read_bytes())[0].image
    det = cfar_detect(image, 10, 5, 0.1, "soca", floor=20.0)
    n = int(det.sum())
    assert 0.001 * image.size < n < 0.03 * image.size
    rows = np.nonzero(det)[0]
    assert np.mean((rows >= 150) & (rows < 450)) > 0.8
    # The cell-averaging variants order as their statistics say: GO <= SOCA in count.
    n_go = int(cfar_detect(image, 10, 5, 0.1, "go", floor=20.0).sum())
    assert n_go <= n
