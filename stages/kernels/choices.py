"""The kernels' named choices that config sections offer (imports nothing heavy).

Config sections are read by planning, which must not import numpy or pyarrow
(docs/decisions/020-cached-run-imports.md); the kernels that implement these choices
import them from here, so each is defined once.
"""

from __future__ import annotations

from typing import Literal

from sonarmap.schemas.classes import DEFAULT_TABLE

__all__ = ["DEFAULT_FRAME_KINDS", "CfarMethod", "ConfidenceRule", "FrameKind", "UpdateRule"]

CfarMethod = Literal["soca", "ca", "go", "os"]
"""CFAR variants of `sonarmap.stages.kernels.cfar`."""

ConfidenceRule = Literal["paper", "ratio"]
"""`fuse.confidence_rule`: "paper" = Eq. 6; "ratio" = the original code's cost ratio
(`sonarmap.stages.kernels.association`)."""

FrameKind = Literal["object", "beam"]
"""The frame a class's height model lives in (`sonarmap.stages.kernels.class_models`)."""

DEFAULT_FRAME_KINDS: dict[str, FrameKind] = DEFAULT_TABLE.frame_kinds()
"""The default class table's frame kinds ('unknown' takes the beam frame)."""

UpdateRule = Literal["product", "mixture"]
"""How a height model folds in a new observation (`sonarmap.stages.kernels.height_model`)."""
