"""Data contracts of sonarmap: column schemas, ROS message definitions, shared value types.

`schemas` imports nothing from `stages`, `sim` or `pipeline`; everything else may import it.
"""

SCHEMA_VERSION = 1
"""Bumped whenever a column contract or a message layout changes (it enters every key)."""

__all__ = ["SCHEMA_VERSION"]
