"""Stage `submaps` (dense submaps between keyframes); see `stages.submaps.stage`."""

from stages.submaps.stage import STAGE

__all__ = ["STAGE"]
