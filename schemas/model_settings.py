"""`ModelSettings`: what a classifier model file says about the objects it was trained on.

The `train` stage stores them in the model file's config beside the network's
architecture; `classify` reads them through this record instead of the raw dict.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["ModelSettings"]


def _number(
    config: Mapping[str, Any], name: str, kind: type, *, optional: bool = False, zero: bool = False
) -> Any:
    """config[name] as `kind`: finite, > 0 (>= 0 with `zero`); None only if `optional`."""
    value = config.get(name)
    if value is None:
        if optional:
            return None
        raise ValueError(f"the model file has no {name!r}")
    ok = isinstance(value, int if kind is int else (int, float)) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or value < 0 or (value == 0 and not zero):
        sign = "non-negative" if zero else "positive"
        raise ValueError(f"the model file's {name!r} is not a {sign} {kind.__name__}")
    return kind(value)


_NORMALISATIONS = ("peak", "background", "grain")


def _normalisation(config: Mapping[str, Any]) -> str:
    value = config.get("patch_normalisation", "peak")
    if value not in _NORMALISATIONS:
        raise ValueError(f"the model file's 'patch_normalisation' is not one of {_NORMALISATIONS}")
    return str(value)


@dataclass(frozen=True)
class ModelSettings:
    """Patch extraction and clustering the model was trained with.

    Attributes:
        size_px: side of the square object patch the network reads [px].
        margin_m: margin around an object's bounding box in its patch [m].
        min_side_m: smallest side of a patch's box [m].
        eps_m, min_samples, min_features: the DBSCAN clustering of features into
            objects (None: a model file written before they were stored).
        patch_normalisation: how patches were scaled (`sonarmap.stages.classify.objects.
            extract_objects`: "peak", "background" or "grain"): "peak" for model files
            written before it was stored.
    """

    size_px: int
    margin_m: float
    min_side_m: float
    eps_m: float | None = None
    min_samples: int | None = None
    min_features: int | None = None
    patch_normalisation: str = "peak"

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ModelSettings:
        """Read the model file's config dict; a ValueError names the bad key."""
        return cls(
            size_px=_number(config, "size_px", int),
            margin_m=_number(config, "margin_m", float, zero=True),
            min_side_m=_number(config, "min_side_m", float, zero=True),
            eps_m=_number(config, "eps_m", float, optional=True),
            min_samples=_number(config, "min_samples", int, optional=True),
            min_features=_number(config, "min_features", int, optional=True),
            patch_normalisation=_normalisation(config),
        )
