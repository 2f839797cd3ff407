"""The object classifier: a small CNN over 40x40 sonar patches with Monte-Carlo dropout.

Paper Sec. IV.C: "a CNN that accepts 40x40 pixel sonar image patches in grayscale,
with two convolutional layers", with m stochastic predictions per object (MC dropout,
Loquercio et al. 2020) so uncertain objects can be labelled "unknown".

Two convolutional layers, as the paper says (the authors' saved Keras models had
three, 80 filters each; docs/authors-code.md §4.2). Why two: the patch content
is a handful of bright strokes (an arc, a corner, a line) whose shape two 3x3 conv +
2x2 pool stages already see at a 10x10-pixel receptive field, two layers reach the
accuracy targets on simulated scenes (tests/test_train.py), and a lean network is what
lets classify run at >= 50 keyframes/s with m = 20 passes on a 2-core CPU.

Shape chain: 40 -> conv 38 -> pool 19 -> conv 17 -> pool 8 -> flatten c2*8*8 -> dense
-> n_classes. Dropout (active in training and at inference) sits after the second conv
block and after the dense layer. Unlike the original, the first conv block has none: both conv blocks are
then deterministic, computed once per patch, and only the dense head runs m times in
one batched call (pass-major), far cheaper than m full passes
(docs/decisions/011-mc-dropout-dense-head-only.md). Masks come from an explicit
`torch.Generator`, so a seed fixes every prediction.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["PatchCNN", "mc_predict", "mc_predict_groups", "model_from_bytes", "model_to_bytes"]

_CONV_CHUNK = 16
"""Patches per conv call: larger batches fall out of the cache and run slower per patch."""


def _dropout(
    x: torch.Tensor, p: float, generator: torch.Generator | None, spatial: bool = False
) -> torch.Tensor:
    """Inverted dropout that is always active, masks drawn from `generator`.

    With `spatial`, (n, c, h, w) inputs lose whole channels; otherwise single units.
    """
    if p <= 0.0:
        return x
    shape = x.shape[:2] + (1,) * (x.dim() - 2) if spatial else x.shape
    keep = torch.rand(shape, generator=generator, dtype=x.dtype) >= p
    if torch.is_inference_mode_enabled():
        # The same values (inputs here are post-ReLU, so no -0.0 either) at a quarter of
        # the cost: the m passes make these activations m-fold. Training keeps the product.
        return torch.where(keep, x, 0.0).div_(1.0 - p)
    return x * keep / (1.0 - p)


def _max_pool2(x: torch.Tensor) -> torch.Tensor:
    """2x2 max pooling, stride 2 (odd trailing rows/columns dropped, as `F.max_pool2d`).

    At inference the pool is the element-wise maximum of four strided views: the same
    values (a maximum rounds nothing) at a seventh of `F.max_pool2d`'s single-thread cost
    on these small maps (it was the largest cost of classify's forward pass). Training
    keeps `F.max_pool2d`, whose gradient picks one element of a tie where
    `torch.maximum` would split it.
    """
    if not torch.is_inference_mode_enabled():
        return F.max_pool2d(x, 2)
    h, w = x.shape[-2] // 2 * 2, x.shape[-1] // 2 * 2
    top = torch.maximum(x[..., 0:h:2, 0:w:2], x[..., 0:h:2, 1:w:2])
    return torch.maximum(top, torch.maximum(x[..., 1:h:2, 0:w:2], x[..., 1:h:2, 1:w:2]))


class PatchCNN(nn.Module):
    """Two conv blocks + one hidden dense layer; MC dropout after conv 2 and the dense layer.

    Args:
        n_classes: number of outputs.
        channels: filters of the two 3x3 conv layers.
        hidden: width of the dense layer.
        dropout_p: dropout probability of every dropout layer.
        size_px: input patch side [px].
        spatial_dropout: drop whole channels after conv 2 instead of single units.
    """

    def __init__(
        self,
        n_classes: int,
        channels: Sequence[int] = (16, 32),
        hidden: int = 64,
        dropout_p: float = 0.1,
        size_px: int = 40,
        spatial_dropout: bool = False,
    ) -> None:
        super().__init__()
        self.spatial_dropout = bool(spatial_dropout)
        c1, c2 = (int(c) for c in channels)
        self.dropout_p = float(dropout_p)
        self.conv1 = nn.Conv2d(1, c1, 3)
        self.conv2 = nn.Conv2d(c1, c2, 3)
        side = ((size_px - 2) // 2 - 2) // 2
        self.fc1 = nn.Linear(c2 * side * side, hidden)
        self.fc2 = nn.Linear(hidden, n_classes)
        for layer in (self.conv1, self.conv2, self.fc1, self.fc2):
            nn.init.xavier_uniform_(layer.weight)
            nn.init.zeros_(layer.bias)

    def forward(
        self, x: torch.Tensor, passes: int = 1, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Logits of `passes` stochastic passes over a batch.

        Args:
            x: (n, 1, size, size) float patches.
            passes: number of MC passes m (the deterministic conv blocks run once).
            generator: source of the dropout masks (None: torch's global generator).

        Returns:
            (passes * n, n_classes) logits, pass-major (row p * n + i = pass p, patch i).
        """
        h = self.features(x)
        if passes > 1:
            h = h.repeat(passes, 1, 1, 1)
        h = _dropout(h, self.dropout_p, generator, self.spatial_dropout)
        h = _dropout(F.relu(self.fc1(h.flatten(1))), self.dropout_p, generator)
        return self.fc2(h)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """(n, 1, size, size) patches -> (n, ...) output of the deterministic conv blocks."""
        if torch.is_inference_mode_enabled():
            # ReLU after the pool: the same values (both are monotone), on a quarter of them.
            h = _max_pool2(self.conv1(x)).relu_()
            return _max_pool2(self.conv2(h)).relu_()
        h = _max_pool2(F.relu(self.conv1(x)))
        return _max_pool2(F.relu(self.conv2(h)))


@contextlib.contextmanager
def fixed_threads(n: int) -> Iterator[None]:
    """Run torch with exactly `n` CPU threads, then restore the previous count.

    Floating-point reductions in torch depend on the thread count, and MC-dropout
    means sit right at the acceptance threshold: without this a Ray worker (one
    thread) and a local run (all cores) accepted different objects from the same
    inputs. A fixed count keeps classify and train byte-deterministic on any machine.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def mc_predict(
    model: PatchCNN, patches: np.ndarray, passes: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Monte-Carlo dropout prediction: mean and variance of m softmax outputs.

    Args:
        model: the classifier.
        patches: (n, size, size) float32 patches in [0, 1].
        passes: number of stochastic passes m (>= 1), batched into one forward call.
        seed: seed of the dropout masks (same seed + same patches -> same output).

    Returns:
        mean (n, n_classes) float64 and variance (n, n_classes) float64 (population
        variance over the passes) of the class probabilities.
    """
    n = len(patches)
    if n == 0:
        c = model.fc2.out_features
        return np.zeros((0, c)), np.zeros((0, c))
    gen = torch.Generator().manual_seed(int(seed))
    x = torch.from_numpy(np.ascontiguousarray(patches, dtype=np.float32))[:, None]
    with torch.inference_mode():
        prob = torch.softmax(model(x, passes=passes, generator=gen), dim=1)
    prob = prob.reshape(passes, n, -1).double()
    return prob.mean(0).numpy(), prob.var(0, unbiased=False).numpy()


def mc_predict_groups(
    model: PatchCNN, patches: np.ndarray, group_sizes: Sequence[int], seeds: Sequence[int],
    passes: int,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Monte-Carlo dropout over many groups of patches (keyframes) at once.

    The same network and m dropout passes as `mc_predict`, but the masks of a pass are
    shared by the patches of one group, drawn from the group's own seed (numpy PCG64).
    Each patch still gets m independent Bernoulli masks with the same p, so its mean and
    variance follow the same distribution as `mc_predict`'s; only patches of one group
    (never pooled with one another, `sonarmap.stages.classify.view_pooling`) share them, and a
    group's output depends only on its patches and its seed (up to float32 rounding of
    the batched products).

    Shared masks make the first dense layer cheap: with D the units a pass drops,
    W (h * keep) = W h - W[:, D] h[D], so W h is computed once per patch for all passes
    and each pass only subtracts its ~p share of the units (one batched product per
    group), instead of m full products over m masked copies of every patch.

    Args:
        model: the classifier.
        patches: (n, size, size) float32 patches in [0, 1], groups in order.
        group_sizes: patches of each group (sum n).
        seeds: seed of each group's masks.
        passes: number of stochastic passes m (>= 1).

    Returns:
        mean (n, n_classes) float64 and population variance (n, n_classes) float64 of
        the class probabilities over the passes.
    """
    n, c = len(patches), model.fc2.out_features
    if n == 0:
        return np.zeros((0, c)), np.zeros((0, c))
    q = 1.0 - model.dropout_p
    units, hidden = model.fc1.in_features, model.fc1.out_features
    # spatial dropout drops whole channels: one draw per channel, spread over its cells
    drawn = model.conv2.out_channels if model.spatial_dropout else units
    x = torch.from_numpy(np.ascontiguousarray(patches, dtype=np.float32))[:, None]
    w_pad = torch.cat([model.fc1.weight.T, torch.zeros(1, hidden)])  # row `units`: padding
    mean, var = np.empty((n, c)), np.empty((n, c))
    ends = np.cumsum(np.asarray(group_sizes, np.int64))
    with torch.inference_mode():
        h = torch.cat([model.features(x[s : s + _CONV_CHUNK]) for s in range(0, n, _CONV_CHUNK)])
        h = torch.cat([h.flatten(1), torch.zeros(n, 1)], dim=1)  # column `units`: padding
        full = h[:, :units] @ model.fc1.weight.T  # W h of every patch, once
        for seed, end, size in zip(seeds, ends, group_sizes, strict=True):
            if size == 0:
                continue
            rows = slice(int(end - size), int(end))
            draw = np.random.default_rng(int(seed)).random((passes, drawn + hidden), np.float32)
            # float32 draws against float32 p: torch.rand's masks drop with the same p
            keep = draw >= np.float32(model.dropout_p)
            drop1 = ~np.repeat(keep[:, :drawn], units // drawn, axis=1)
            dropped = _padded_indices(drop1, units)  # (m, d)
            corr = torch.bmm(h[rows][:, dropped].transpose(0, 1), w_pad[dropped])  # (m, b, hidden)
            pre = (full[rows][None] - corr).div_(q) + model.fc1.bias
            keep2 = torch.from_numpy(keep[:, None, drawn:])
            a = torch.where(keep2, F.relu(pre), 0.0).div_(q)
            prob = torch.softmax(model.fc2(a), dim=-1).double()
            mean[rows] = prob.mean(0).numpy()
            var[rows] = prob.var(0, unbiased=False).numpy()
    return mean, var


def _padded_indices(mask: np.ndarray, pad: int) -> torch.Tensor:
    """(m, units) bool -> (m, d) int64 column indices of the True entries of each row, in
    order, rows padded to the longest with `pad`."""
    counts = mask.sum(axis=1)
    out = np.full((len(mask), int(counts.max(initial=0))), pad, np.int64)
    row, col = np.nonzero(mask)
    out[row, np.arange(len(row)) - np.repeat(np.cumsum(counts) - counts, counts)] = col
    return torch.from_numpy(out)


def model_to_bytes(model: PatchCNN, class_names: Sequence[str], config: dict[str, Any]) -> bytes:
    """Serialise {"state_dict", "class_names", "config"} with torch.save (weights_only-safe).

    `config` must hold the architecture keys `channels`, `hidden`, `dropout_p`,
    `size_px` plus anything the patch extraction needs (plain JSON-like values only).
    """
    buf = io.BytesIO()
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    torch.save({"state_dict": state, "class_names": list(class_names), "config": config}, buf)
    return buf.getvalue()


def model_from_bytes(data: bytes) -> tuple[PatchCNN, list[str], dict[str, Any]]:
    """Inverse of `model_to_bytes`, loading with `weights_only=True`.

    Returns:
        (model in eval mode, class names, config).

    Raises:
        ValueError: when the bytes are not a model file of this project.
    """
    try:
        blob = torch.load(io.BytesIO(data), weights_only=True, map_location="cpu")
        names = [str(s) for s in blob["class_names"]]
        cfg = dict(blob["config"])
        model = PatchCNN(
            len(names), cfg["channels"], cfg["hidden"], cfg["dropout_p"], cfg["size_px"],
            bool(cfg.get("spatial_dropout", False)),
        )  # fmt: skip
        model.load_state_dict(blob["state_dict"])
    except Exception as err:  # any failure to parse untrusted bytes is a bad file
        # torch's own message is several lines and suggests loading unsafely: only
        # the kind of failure is kept.
        raise ValueError(
            f"not a weights-only state dict of a sonarmap classifier model file "
            f"({type(err).__name__}); refused without running any of its code"
        ) from err
    return model.eval(), names, cfg
