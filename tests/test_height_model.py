"""HeightModel (paper Eq. 7-9): Bayes update, max-mixture, two-halves MAP, sparse cells."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.stages.kernels.height_model import HeightModel, z_grid

Z = z_grid(-2.0, 2.0, 0.05)


def _model(**kw: float) -> HeightModel:
    return HeightModel(Z, sigma_m=0.08, range_cell_m=0.05, cross_range_cell_m=0.1, **kw)


def test_z_grid_is_inclusive_and_evenly_spaced() -> None:
    assert Z.size == 81
    assert Z[0] == -2.0 and Z[-1] == 2.0
    np.testing.assert_allclose(np.diff(Z), 0.05)
    with pytest.raises(ValueError):
        z_grid(1.0, -1.0, 0.05)


def test_single_measurement_gives_its_height_in_its_half_only() -> None:
    m = _model()
    m.update(np.array([[0.26, 0.02]]), np.array([0.52]))
    q = m.query(np.array([[0.27, 0.03]]), threshold=0.3)  # same cell
    assert q.z_high_m[0] == pytest.approx(0.5)
    assert q.conf_high[0] > 0.6
    assert np.isnan(q.z_low_m[0])  # lower half has no mass near its MAP


def test_unseen_cell_and_fresh_model_give_nothing() -> None:
    m = _model()
    assert not m.updated
    q = m.query(np.array([[0.0, 0.0]]), threshold=0.0)
    assert np.isnan(q.z_low_m).all() and np.isnan(q.z_high_m).all()
    m.update(np.array([[0.0, 0.0]]), np.array([0.2]))
    q = m.query(np.array([[1.0, 1.0]]), threshold=0.0)
    assert np.isnan(q.z_high_m[0]) and np.isnan(q.conf_high[0])


def test_negative_offsets_are_separate_cells() -> None:
    m = _model()
    uv = np.array([[-0.12, -0.33], [0.12, 0.33], [-0.12, 0.33]])
    m.update(uv, np.array([-0.6, 0.4, 1.1]))
    assert m.n_cells == 3
    q = m.query(uv, threshold=0.3)
    np.testing.assert_allclose(q.z_low_m[0], -0.6)
    np.testing.assert_allclose(q.z_high_m[1:], [0.4, 1.1])


def test_max_mixture_within_a_keyframe_keeps_both_modes() -> None:
    uv = np.array([[0.2, 0.0], [0.21, 0.01]])  # same cell
    mixed = _model()
    mixed.update(uv, np.array([-0.5, 0.5]))
    q = mixed.query(uv[:1], threshold=0.3)
    assert q.z_low_m[0] == pytest.approx(-0.5) and q.z_high_m[0] == pytest.approx(0.5)
    assert q.conf_low[0] == pytest.approx(q.conf_high[0], rel=1e-6)
    # The same two heights in two keyframes multiply (Eq. 7 applied twice): one mode at 0.
    sequential = _model()
    sequential.update(uv[:1], np.array([-0.5]))
    sequential.update(uv[1:], np.array([0.5]))
    q = sequential.query(uv[:1], threshold=0.3)
    assert q.z_low_m[0] == pytest.approx(0.0)
    assert np.isnan(q.z_high_m[0])


def test_update_matches_dense_reference_loop() -> None:
    rng = np.random.default_rng(3)
    m = _model()
    cells: dict[tuple[int, int], np.ndarray] = {}
    for _ in range(6):  # keyframes
        uv = rng.uniform(-0.3, 0.3, (40, 2))
        z = rng.normal(0.2, 0.6, 40)
        m.update(uv, z)
        # Slow reference: per cell, max-mixture of Gaussians times prior, normalised.
        ij = np.floor(uv / [0.05, 0.1] + 0.5).astype(int)  # cells centred on multiples
        inside = (z >= Z[0]) & (z <= Z[-1])
        for key in {tuple(k) for k in ij[inside]}:
            sel = inside & (ij == key).all(axis=1)
            lik = np.max(np.exp(-0.5 * ((Z[None] - z[sel, None]) / 0.08) ** 2), axis=0)
            prior = cells.get(key, np.full(Z.size, 1.0 / Z.size))
            cells[key] = lik * prior / np.sum(lik * prior)
    keys = list(cells)
    centres = np.array(keys) * [0.05, 0.1]
    got = np.exp(m.log_posterior(centres))
    np.testing.assert_allclose(got, np.array([cells[k] for k in keys]), atol=1e-9)
    assert m.n_cells == len(cells)


def test_repeated_consistent_measurements_raise_confidence() -> None:
    m = _model()
    uv = np.array([[0.0, 0.0]])
    confs = []
    for z in (-0.71, -0.69, -0.7, -0.72):
        m.update(uv, np.array([z]))
        confs.append(m.query(uv, threshold=0.0).conf_low[0])
    assert np.all(np.diff(confs) > 0)
    assert confs[-1] > 0.95


def test_threshold_filters_vague_posteriors() -> None:
    m = _model()
    uv = np.zeros((5, 2))
    m.update(uv, np.array([0.1, 0.4, 0.7, 1.0, 1.3]))  # broad max-mixture in one cell
    q = m.query(uv[:1], threshold=0.5)
    assert np.isnan(q.z_high_m[0])
    q = m.query(uv[:1], threshold=0.1)
    assert 0.1 <= q.z_high_m[0] <= 1.3


def test_coarse_fallback_answers_only_where_the_fine_cell_is_empty() -> None:
    """`CoarseFallbackModel`: a fine cell with data answers as the plain model does; an
    empty fine cell inside a coarse cell with data takes the coarse answer; a position
    with no data at either level predicts nothing."""
    from sonarmap.stages.kernels.fallback_model import CoarseFallbackModel

    z = z_grid(-2.0, 2.0, 0.05)
    plain = HeightModel(z, 0.08, 0.1, 0.1, 0.08)
    model = CoarseFallbackModel(HeightModel(z, 0.08, 0.1, 0.1, 0.08), factor=2)
    trained = np.array([[0.0, 0.0], [1.0, 1.0]])
    heights = np.array([-0.5, 0.7])
    for m in (plain, model):
        for _ in range(3):
            m.update(trained, heights)
    # (0.06, 0): its own 0.1 m cell (centred on 0.1) is empty, its 0.2 m cell holds (0, 0);
    # (3, 3): nothing near it at either level.
    probe = np.array([[0.0, 0.0], [1.0, 1.0], [0.06, 0.0], [3.0, 3.0]])
    got, ref = model.query(probe, 0.3), plain.query(probe, 0.3)
    np.testing.assert_array_equal(got.seen, [True, True, True, False])
    np.testing.assert_array_equal(ref.seen, [True, True, False, False])
    np.testing.assert_array_equal(got.z_low_m[:2], ref.z_low_m[:2])
    np.testing.assert_array_equal(got.z_high_m[:2], ref.z_high_m[:2])
    assert got.z_low_m[2] == pytest.approx(-0.5, abs=0.05)
    assert np.isnan(got.z_low_m[3]) and np.isnan(got.z_high_m[3])
    assert model.n_cells == plain.n_cells == 2 and model.updated
    with pytest.raises(ValueError, match="factor"):
        CoarseFallbackModel(HeightModel(z), factor=1)


def test_profile_level_answers_any_cross_range_of_a_trained_range() -> None:
    """With `profile`, a position whose fine and coarse cells are empty takes the height
    the class's other cells at its range learned (pooled over cross-range), and only
    there: a range no cell learned still predicts nothing; where the coarse cell has data
    the profile is not asked."""
    from sonarmap.stages.kernels.fallback_model import CoarseFallbackModel

    z = z_grid(-2.0, 2.0, 0.05)
    two = CoarseFallbackModel(HeightModel(z, 0.08, 0.1, 0.1, 0.08), factor=2)
    three = CoarseFallbackModel(HeightModel(z, 0.08, 0.1, 0.1, 0.08), factor=2, profile=True)
    # A vertical face seen at one cross-range only: z = -s at s = 1.0 m.
    for m in (two, three):
        for _ in range(3):
            m.update(np.array([[1.0, 0.0], [0.4, 2.0]]), np.array([-1.0, 0.9]))
    probe = np.array([[1.0, 0.0], [1.0, -1.5], [1.0, 3.0], [2.6, 0.0]])
    got, ref = three.query(probe, 0.3), two.query(probe, 0.3)
    np.testing.assert_array_equal(ref.seen, [True, False, False, False])
    np.testing.assert_array_equal(got.seen, [True, True, True, False])
    assert got.z_low_m[:3] == pytest.approx([-1.0, -1.0, -1.0], abs=0.05)
    assert np.isnan(got.z_high_m[:3]).all()  # the 0.4 m range's +0.9 m stays there
    assert three.profile is not None and three.profile.n_cells == 2
