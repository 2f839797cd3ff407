"""The MC-dropout CNN: shapes, seeded determinism, batched passes, model file round trip."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from sonarmap.stages.classify.cnn import (
    PatchCNN,
    mc_predict,
    mc_predict_groups,
    model_from_bytes,
    model_to_bytes,
)


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


def _model(p: float = 0.3) -> PatchCNN:
    torch.manual_seed(0)
    return PatchCNN(4, (8, 16), 32, p).eval()


def _patches(n: int = 5) -> np.ndarray:
    return np.random.default_rng(0).random((n, 40, 40)).astype(np.float32)


def test_forward_returns_pass_major_logits() -> None:
    out = _model()(torch.rand(3, 1, 40, 40), passes=7, generator=torch.Generator().manual_seed(1))
    assert out.shape == (21, 4)


def test_mc_predict_is_seeded_and_varies_between_passes() -> None:
    model, x = _model(), _patches()
    m1, v1 = mc_predict(model, x, 20, seed=3)
    m2, v2 = mc_predict(model, x, 20, seed=3)
    m3, _ = mc_predict(model, x, 20, seed=4)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(v1, v2)
    assert not np.array_equal(m1, m3)
    np.testing.assert_allclose(m1.sum(axis=1), 1.0, atol=1e-9)
    assert (v1 > 0).all()  # dropout stays active at inference


def test_without_dropout_every_pass_equals_the_plain_forward() -> None:
    model, x = _model(p=0.0), _patches()
    mean, var = mc_predict(model, x, 10, seed=0)
    with torch.no_grad():
        ref = torch.softmax(model(torch.from_numpy(x)[:, None]), 1).double().numpy()
    np.testing.assert_allclose(mean, ref, atol=1e-6)
    np.testing.assert_allclose(var, 0.0, atol=1e-12)


def test_batched_passes_equal_separate_passes_with_the_same_masks() -> None:
    """The pass-major batch is m independent passes: rebuilding each pass by hand from
    the same generator stream reproduces the batched result."""
    model, x = _model(), _patches(3)
    mean, var = mc_predict(model, x, 4, seed=9)
    gen = torch.Generator().manual_seed(9)
    xt = torch.from_numpy(x)[:, None]
    with torch.no_grad():
        h = torch.nn.functional.max_pool2d(torch.relu(model.conv1(xt)), 2)
        h = torch.nn.functional.max_pool2d(torch.relu(model.conv2(h)), 2)
        keep1 = torch.rand((12, *h.shape[1:]), generator=gen) >= model.dropout_p
        keep2 = torch.rand((12, model.fc1.out_features), generator=gen) >= model.dropout_p
        probs = []
        for p in range(4):
            rows = slice(3 * p, 3 * p + 3)
            hp = h * keep1[rows] / (1 - model.dropout_p)
            hp = torch.relu(model.fc1(hp.flatten(1))) * keep2[rows] / (1 - model.dropout_p)
            probs.append(torch.softmax(model.fc2(hp), 1).double().numpy())
    np.testing.assert_allclose(mean, np.mean(probs, axis=0), atol=1e-6)
    np.testing.assert_allclose(var, np.var(probs, axis=0), atol=1e-6)


def test_model_file_round_trips_with_weights_only() -> None:
    model, x = _model(), _patches()
    cfg = {"channels": [8, 16], "hidden": 32, "dropout_p": 0.3, "size_px": 40, "margin_m": 0.2}
    data = model_to_bytes(model, ["a", "b", "c", "d"], cfg)
    blob = torch.load(io.BytesIO(data), weights_only=True)
    assert blob["class_names"] == ["a", "b", "c", "d"]
    assert blob["config"] == cfg
    loaded, names, cfg2 = model_from_bytes(data)
    assert names == ["a", "b", "c", "d"] and cfg2 == cfg
    np.testing.assert_array_equal(mc_predict(loaded, x, 5, 1)[0], mc_predict(model, x, 5, 1)[0])
    assert model_to_bytes(model, ["a", "b", "c", "d"], cfg) == data


def test_garbage_model_bytes_raise_value_error() -> None:
    with pytest.raises(ValueError, match="model file"):
        model_from_bytes(b"not a model")


def test_no_patches_give_empty_predictions() -> None:
    mean, var = mc_predict(_model(), np.zeros((0, 40, 40), np.float32), 20, 0)
    assert mean.shape == (0, 4) and var.shape == (0, 4)


@pytest.mark.parametrize("side", [38, 17, 2, 3])
def test_inference_pooling_equals_max_pool2d_bit_for_bit(side: int) -> None:
    from torch.nn import functional as F

    from sonarmap.stages.classify.cnn import _max_pool2

    x = torch.randn(3, 4, side, side, generator=torch.Generator().manual_seed(side))
    x[0, 0] = 0.0  # ties
    with torch.inference_mode():
        assert torch.equal(_max_pool2(F.relu(x)), F.max_pool2d(F.relu(x), 2))


def test_grouped_prediction_without_dropout_equals_the_plain_forward() -> None:
    """p = 0: the shared-mask correction W[:, D] h[D] is empty, so every pass is the
    deterministic network (up to float32 rounding of W h computed once)."""
    model, x = _model(0.0), _patches(7)
    mean, var = mc_predict_groups(model, x, [3, 0, 4], [1, 2, 3], 5)
    with torch.inference_mode():
        plain = torch.softmax(model(torch.from_numpy(x)[:, None]), dim=1).double().numpy()
    np.testing.assert_allclose(mean, plain, atol=1e-6)
    np.testing.assert_array_equal(var, 0.0)


@pytest.mark.parametrize("spatial", [False, True])
def test_grouped_prediction_matches_per_patch_masks_in_distribution(spatial: bool) -> None:
    """Masks shared by a group's patches: each patch's MC mean and variance converge to
    those of per-patch masks (`mc_predict`); seeded, and one group's output does not
    depend on the others'."""
    model = PatchCNN(3, channels=(4, 8), hidden=16, dropout_p=0.3, spatial_dropout=spatial)
    x = _patches(6)
    mean, var = mc_predict_groups(model, x, [2, 4], [7, 8], 4000)
    ref_mean, ref_var = mc_predict(model, x, 4000, 0)
    np.testing.assert_allclose(mean, ref_mean, atol=0.02)
    np.testing.assert_allclose(var, ref_var, atol=0.02)
    assert var.max() > 0.001  # the passes do differ
    again = mc_predict_groups(model, x, [2, 4], [7, 8], 20)
    np.testing.assert_array_equal(again[0], mc_predict_groups(model, x, [2, 4], [7, 8], 20)[0])
    alone = mc_predict_groups(model, x[2:], [4], [8], 20)[0]
    np.testing.assert_allclose(alone, again[0][2:], rtol=1e-6)
    assert not np.allclose(mc_predict_groups(model, x[2:], [4], [9], 20)[0], alone)
