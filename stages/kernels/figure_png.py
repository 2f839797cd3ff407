"""A stage figure as PNG bytes: Agg in memory, no file, no software or date metadata, so
the same data give the same bytes (every figure of every stage is written this way)."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["png_bytes"]


def png_bytes(fig: Figure) -> bytes:
    """`fig` rendered by Agg to PNG bytes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()
