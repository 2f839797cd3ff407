"""Training images at other sensors' noise floors (issue 50): noisy copies of a ping.

A model trained on the simulator's clean sensor (background median ~4 of 255) meets real
sensors whose additive noise is far brighter and more speckled (Oculus M1200d: median 43,
speckle contrast 0.64; ARIS: 89 / 0.28). Each training keyframe's horizontal image is
therefore also shown with extra additive noise of the simulator's own model
(`sonarmap.sim.sonar`: Weibull amplitude of a given mean level and shape, added to the
returns and clipped to 255), drawn per copy from the ranges of `sonarmap.sim.randomise`
(mean log-uniform, shape uniform). The objects stay the ones found on the clean image,
so the copies teach the network what an object looks like through any noise floor, not
where a detector finds one. Deterministic: each copy's draw is seeded by (seed, dataset,
keyframe, copy).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["noisy_image"]


def noisy_image(
    image: np.ndarray,
    mean_level: tuple[float, float],
    shape: tuple[float, float],
    seed: tuple[int, ...],
) -> np.ndarray:
    """`image` plus one draw of additive Weibull noise, clipped to uint8.

    Args:
        image: (n_ranges, n_beams) uint8 polar image.
        mean_level: (low, high) mean of the added noise [8-bit levels], log-uniform.
        shape: (low, high) Weibull shape of the added noise (2: Rayleigh), uniform.
        seed: entropy of this copy's generator.

    Returns:
        (n_ranges, n_beams) uint8 image.
    """
    rng = np.random.default_rng(list(seed))
    mean = math.exp(rng.uniform(math.log(mean_level[0]), math.log(mean_level[1])))
    k = rng.uniform(*shape)
    scale = mean / math.gamma(1.0 + 1.0 / k)
    noise = scale * rng.weibull(k, image.shape)
    return np.minimum(image + noise + 0.5, 255.0).astype(np.uint8)
