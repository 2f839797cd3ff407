"""Resource limits on what a recording may declare: decompressed chunk and image sizes.

A recording is untrusted input: a chunk may declare any uncompressed size, and a
compressed payload may expand far beyond what it declares. Every decompression is
capped at the size the record declares, and the declared size itself at
`max_chunk_bytes()`, so memory follows the limit whatever the file claims.
"""

from __future__ import annotations

import os

from sonarmap.pipeline.engine.errors import ConfigError

__all__ = [
    "CHUNK_LIMIT_ENV",
    "DEFAULT_MAX_CHUNK_MB",
    "MAX_IMAGE_PIXELS",
    "max_chunk_bytes",
]

CHUNK_LIMIT_ENV = "SONARMAP_MAX_CHUNK_MB"
"""Environment variable overriding the largest uncompressed chunk accepted [MiB]."""

DEFAULT_MAX_CHUNK_MB = 256
"""Recorders write chunks of a few MB (rosbag2's default is 768 kB, ROS 1's 768 kB, the
MCAP CLI's 4 MB); a chunk declaring more than this is refused rather than allocated."""

MAX_IMAGE_PIXELS = 64 * 1024 * 1024
"""Largest decoded image (sonar ping, label or truth image) [pixels]; a sonar image is
well under a megapixel."""


def max_chunk_bytes() -> int:
    """The largest declared uncompressed chunk size accepted [bytes].

    Raises:
        ConfigError: the environment variable is set but not a positive whole number.
    """
    raw = os.environ.get(CHUNK_LIMIT_ENV, "").strip()
    if not raw:
        return DEFAULT_MAX_CHUNK_MB << 20
    if not raw.isdigit() or len(raw) > 7 or int(raw) <= 0:
        raise ConfigError(
            f"{CHUNK_LIMIT_ENV}={raw[:20]!r}: expected a whole number of MiB (1 to 9999999)"
        )
    return int(raw) << 20
