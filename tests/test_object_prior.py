"""Per-object height prior of the beam-frame models (stages.kernels.object_prior)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarmap.stages.kernels.height_model import HeightModel, z_grid
from sonarmap.stages.kernels.object_prior import object_height_prior

Z = z_grid(-2.0, 2.0, 0.05)


def test_prior_peaks_at_each_objects_own_heights_and_is_flat_without_them() -> None:
    prior = object_height_prior(
        Z,
        fused_object_id=np.array([7, 7, 3]),
        fused_z_m=np.array([1.0, 1.1, -0.5]),
        query_object_id=np.array([3, 7, 9, 7]),
        sigma_m=0.1,
        floor=0.05,
    )
    assert prior.shape == (4, Z.size)
    assert Z[np.argmax(prior[0])] == pytest.approx(-0.5)
    assert 1.0 <= Z[np.argmax(prior[1])] <= 1.1
    np.testing.assert_array_equal(prior[1], prior[3])
    np.testing.assert_array_equal(prior[2], np.ones(Z.size))  # object 9: no fused point
    assert prior[:2].max() == pytest.approx(1.05) and prior[:2].min() == pytest.approx(0.05)
    with pytest.raises(ValueError):
        object_height_prior(Z, [1], [0.0], [1], sigma_m=0.0, floor=0.0)


def test_prior_picks_the_objects_band_out_of_a_pooled_class_posterior() -> None:
    """Two objects of one class at different heights (a hull's keel at +0.4 m, another's
    at +1.4 m) fill the same model cell; the class posterior alone gives one height for
    both, the object prior gives each its own."""
    m = HeightModel(Z, 0.08, 0.1, 1.0, 0.08, "mixture")
    cell = np.zeros((1, 2))
    for _ in range(3):
        m.update(cell, np.array([0.4]))
    for _ in range(2):
        m.update(cell, np.array([1.4]))
    pooled = m.query(np.zeros((2, 2)), threshold=0.0)
    assert pooled.z_high_m == pytest.approx([0.4, 0.4])
    prior = object_height_prior(Z, [1, 2], [0.45, 1.35], [1, 2], sigma_m=0.2, floor=0.0)
    own = m.query(np.zeros((2, 2)), threshold=0.0, prior=prior)
    assert own.z_high_m == pytest.approx([0.4, 1.4])
    assert own.conf_high[1] > 0.9  # the product's mass is the object's band
