"""Sonar image geometry against ground truth on one-object scenes (sim.sonar)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.schemas.sonar import SonarPing
from sonarmap.sim.config import SimConfig
from sonarmap.sim.scene import Scene
from sonarmap.sim.sonar import SonarModel
from sonarmap.sim.world import World
from sonarmap.stages.kernels.geometry import se3_from_pose as pose_to_matrix

ROOT = Path(__file__).resolve().parent.parent

CFG = SimConfig()
PILING = CLASS_IDS["cylindrical_piling"]
APERTURE_HALF = np.deg2rad(10.0)


def _scene(*objects: dict) -> Scene:
    return Scene.model_validate(
        {"area_m": [-20, 20, -20, 20], "seafloor_depth_m": 8.0, "objects": list(objects)}
    )


def _ping(scene: Scene, sonar: str, seed: int = 0) -> SonarPing:
    """A ping with base_link at (0, 0, -2) facing +x."""
    cfg = CFG.sonar(sonar)
    T = pose_to_matrix(np.array([0.0, 0.0, -2.0, 0.0, 0.0, 0.0])) @ cfg.mounting.matrix()
    return SonarModel(cfg, sonar).render(World(scene), T, np.random.default_rng(seed), 0)


def _pixels(ping: SonarPing, cls: int) -> tuple[np.ndarray, np.ndarray]:
    assert ping.labels is not None
    rows, cols = np.nonzero(ping.labels == cls)
    return ping.ranges_m[rows].astype(float), ping.angles_rad[cols].astype(float)


def test_piling_lands_at_its_range_and_bearing_with_elevation_smear() -> None:
    # Front face at horizontal distance d = 9.75 m from the sonar (x = 0.5 m), bearing 0.
    ping = _ping(
        _scene({"class": "cylindrical_piling", "position_m": [10.5, 0.0], "radius_m": 0.25}),
        "horizontal",
    )
    r, a = _pixels(ping, PILING)
    d, res = 9.75, 0.05
    central = np.abs(a) < np.deg2rad(0.3)
    assert central.sum() > 0
    assert r[central].min() == pytest.approx(d, abs=res)
    assert r[central].max() == pytest.approx(d / np.cos(APERTURE_HALF), abs=2 * res)
    half_width = np.arcsin(0.25 / 10.0)
    # Labels span the piling's angular width widened by the beam pattern (1 deg FWHM).
    beam_width = np.deg2rad(CFG.horizontal.beam_width_deg)
    assert -half_width - beam_width <= a.min() <= -half_width + np.deg2rad(0.3)
    assert half_width - np.deg2rad(0.3) <= a.max() <= half_width + beam_width
    assert abs(np.average(a, weights=ping.image[ping.labels == PILING])) < np.deg2rad(0.3)
    # The image is bright where the labels are, dark elsewhere.
    assert ping.image[ping.labels == PILING].mean() > 5 * ping.image[ping.labels == 0].mean()


def test_piling_spans_its_true_elevations_in_the_vertical_image() -> None:
    ping = _ping(
        _scene({"class": "cylindrical_piling", "position_m": [10.5, 0.0], "radius_m": 0.25}),
        "vertical",
    )
    r, a = _pixels(ping, PILING)
    d, z_sonar = 9.75, -1.9
    assert a.min() == pytest.approx(np.arctan2(-8.0 - z_sonar, d), abs=np.deg2rad(1.0))
    assert a.max() == pytest.approx(np.arctan2(1.0 - z_sonar, d), abs=np.deg2rad(1.0))
    # Per beam, the nearest return is at d / cos(elevation).
    beams = np.unique(a)[3:-3]  # away from the partially filled top and bottom beams
    nearest = np.array([r[a == b].min() for b in beams])
    np.testing.assert_allclose(nearest, d / np.cos(beams), atol=0.1)
    # Truth angle (bearing) of the piling pixels is within the piling's angular half-width.
    assert ping.truth_angle_rad is not None
    truth = ping.truth_angle_rad[ping.labels == PILING]
    assert np.all(np.abs(truth) < np.arcsin(0.25 / 9.75) + 0.01)


def test_target_above_the_sonar_plane_at_slant_range_and_true_elevation() -> None:
    # A small floating frame centred 1.2 m above the horizontal sonar, 7.5 m ahead of it.
    frame = {
        "class": "truss",
        "start_m": [8.0, -0.4],
        "end_m": [8.0, 0.4],
        "top_z_m": -0.7,
        "bottom_z_m": -0.9,
        "member_width_m": 0.1,
        "bays": 1,
    }
    truss = CLASS_IDS["truss"]
    h = _ping(_scene(frame), "horizontal")
    r, a = _pixels(h, truss)
    assert len(r) > 0
    assert abs(np.median(a)) < np.deg2rad(1.0)
    assert np.median(r) == pytest.approx(np.hypot(7.45, 1.2), abs=0.15)
    assert h.truth_angle_rad is not None
    elev = h.truth_angle_rad[h.labels == truss]
    assert np.median(elev) == pytest.approx(np.arctan2(1.2, 7.45), abs=np.deg2rad(1.0))
    v = _ping(_scene(frame), "vertical")
    r_v, a_v = _pixels(v, truss)
    assert np.median(a_v) == pytest.approx(np.arctan2(1.1, 7.45), abs=np.deg2rad(1.0))
    assert np.median(r_v) == pytest.approx(np.hypot(7.45, 1.1), abs=0.15)


def test_labels_name_the_object_classes() -> None:
    scene = _scene(
        {"class": "cylindrical_piling", "position_m": [8.0, 3.0], "radius_m": 0.3},
        {"class": "rectangular_piling", "position_m": [8.0, -3.0], "width_m": 0.5, "depth_m": 0.5},
    )
    ping = _ping(scene, "horizontal")
    _, a_round = _pixels(ping, PILING)
    _, a_square = _pixels(ping, CLASS_IDS["rectangular_piling"])
    assert np.median(a_round) == pytest.approx(np.arctan2(3.0, 7.5), abs=np.deg2rad(2))
    assert np.median(a_square) == pytest.approx(np.arctan2(-3.0, 7.5), abs=np.deg2rad(2))
    assert set(np.unique(ping.labels)) <= {0, PILING, CLASS_IDS["rectangular_piling"]}


def test_overlap_region_target_in_both_fans_only_there() -> None:
    scene = _scene(
        {"class": "cylindrical_piling", "position_m": [10.5, 0.0], "radius_m": 0.25},
        {"class": "rectangular_piling", "position_m": [5.0, 6.0]},
    )
    h, v = _ping(scene, "horizontal"), _ping(scene, "vertical")
    assert (h.labels == PILING).any() and (v.labels == PILING).any()
    square = CLASS_IDS["rectangular_piling"]
    assert (h.labels == square).any()
    assert not (v.labels == square).any()


def test_seafloor_seen_by_vertical_sonar_at_depth() -> None:
    v = _ping(_scene(), "vertical")
    r, a = _pixels(v, CLASS_IDS["seafloor"])
    h_below = 8.0 - 1.9
    # Within the beam's across-fan width (0.6 deg FWHM) of the true floor.
    tol = 0.1 + r * np.cos(a) * np.deg2rad(CFG.vertical.beam_width_deg)
    assert np.all(np.abs(r * np.sin(-a) - h_below) <= tol)
    assert np.median(np.abs(r * np.sin(-a) - h_below)) < 0.2


def test_thin_far_pilings_are_never_missed() -> None:
    # 0.2 m pilings at 25-28 m: every one in the horizontal image, and in the vertical
    # image every elevation beam between the seafloor and the surface sees the one ahead.
    bearings = np.deg2rad([-50.0, -20.0, 0.0, 7.0, 33.0, 61.0])
    objs = [
        {
            "class": "cylindrical_piling",
            "position_m": [0.5 + 26.0 * np.cos(b), 26.0 * np.sin(b)],
            "radius_m": 0.1,
        }
        for b in bearings
    ]
    scene = Scene.model_validate(
        {"area_m": [-40, 40, -40, 40], "seafloor_depth_m": 8.0, "objects": objs}
    )
    for seed in range(3):
        h = _ping(scene, "horizontal", seed)
        _, a = _pixels(h, PILING)
        for b in bearings:
            assert np.any(np.abs(a - b) < np.deg2rad(1.0)), np.rad2deg(b)
        v = _ping(scene, "vertical", seed)
        assert v.labels is not None
        lo, hi = np.arctan2(-8.0 + 1.9, 25.9) + 0.01, np.arctan2(1.0 + 1.9, 25.9) - 0.01
        cols = np.flatnonzero((v.angles_rad > lo) & (v.angles_rad < hi))
        assert np.all((v.labels[:, cols] == PILING).any(axis=0))


@pytest.mark.parametrize("y_m", [-1.0, 1.0])
def test_vertical_truth_bearing_sign_follows_rep103(y_m: float) -> None:
    scene = _scene({"class": "cylindrical_piling", "position_m": [10.5, y_m], "radius_m": 0.2})
    v = _ping(scene, "vertical")
    assert v.truth_angle_rad is not None and v.labels is not None
    truth = v.truth_angle_rad[v.labels == PILING]
    assert np.median(truth) == pytest.approx(np.arctan2(y_m, 10.0), abs=np.deg2rad(0.7))


def _strongest_reference(pix: np.ndarray, w: np.ndarray, ray: np.ndarray) -> dict[int, int]:
    """Per pixel, the entry of largest weight, the later of equals (a plain loop)."""
    best: dict[int, tuple[float, int]] = {}
    for p, wi, r in zip(pix.tolist(), w.tolist(), ray.tolist(), strict=True):
        if p not in best or wi >= best[p][0]:
            best[p] = (wi, r)
    return {p: r for p, (_, r) in best.items()}


def test_strongest_ray_per_pixel_matches_a_loop_ties_to_the_later_ray() -> None:
    from sonarmap.sim.sonar import _strongest

    rng = np.random.default_rng(0)
    for _ in range(50):
        n_rays, size = int(rng.integers(1, 40)), 30
        per_ray = rng.integers(1, 6, n_rays)
        ray = np.repeat(np.arange(n_rays), per_ray)
        # Few distinct weights, so ties are common; one weight per ray, as _splat gives.
        w = np.repeat(rng.integers(1, 4, n_rays).astype(np.float64) / 7, per_ray)
        pix = np.concatenate([rng.choice(size, k, replace=False) for k in per_ray])
        top_pix, top_ray = _strongest(pix, w, ray, size)
        expected = _strongest_reference(pix, w, ray)
        assert top_pix.tolist() == sorted(expected)
        assert top_ray.tolist() == [expected[p] for p in sorted(expected)]
    empty = np.zeros(0, np.int64)
    assert [a.tolist() for a in _strongest(empty, np.zeros(0), empty, 5)] == [[], []]


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        ("position_m: [6.0, 3.0]|position_m: [.nan, 3.0]", "position_m[0] = nan: Input should be a finite"),
        ("area_m: [-15.0, 15.0, -15.0, 15.0]|area_m: [-1.0e7, 1.0e7, -15, 15]", "area_m must span at most"),
        ("area_m: [-15.0, 15.0, -15.0, 15.0]|area_m: [-15, 15, -15, 15]\nseafloor_margin_m: 1.0e9", "seafloor_margin_m"),
    ],
    ids=["nan-position", "ocean-sized-area", "huge-margin"],
)
def test_a_scene_that_is_not_finite_or_not_a_harbour_is_refused_in_one_line(
    tmp_path: Path, edit: str, words: str
) -> None:
    """A NaN position wrote a recording with corrupt ground truth (exit 0); an area of
    1e7 m asked for a 29 TiB seafloor grid (exit 1). Both are one line, exit 2."""
    from typer.testing import CliRunner

    from sonarmap.pipeline.cli import app

    old, new = edit.split("|")
    text = (ROOT / "configs" / "scenes" / "tiny.yaml").read_text()
    assert old in text
    scene = tmp_path / "scene.yaml"
    scene.write_text(text.replace(old, new))
    out = tmp_path / "x.mcap"
    args = ["simulate", "-o", str(out), "--scene", str(scene), "--goals", "1"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and words in lines[0] and ": : " not in lines[0], lines
    assert not out.exists()
