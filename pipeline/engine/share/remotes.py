"""Remotes as fsspec filesystems: local paths, `s3://`, `ssh://`/`sftp://`, `http(s)://`.

Credentials come from the places each library already reads (AWS environment and
config files for s3fs; ssh config, agent and keys for sshfs/asyncssh); sonarmap never
stores them. A URL may still carry a password (`sftp://user:secret@host/...`), so every
message names a remote through `display`, which drops the user-info part.
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from sonarmap.pipeline.engine.errors import StoreError

__all__ = ["display", "open_remote", "read_only"]

_EXTRAS = {
    "s3": "s3fs",
    "s3a": "s3fs",
    "ssh": "sshfs",
    "sftp": "sshfs",
    "http": "aiohttp",
    "https": "aiohttp",
    "gs": "gcsfs",
}
_IN_EXTRA = {"s3", "s3a", "ssh", "sftp", "http", "https"}
"""Schemes whose library the `remotes` extra installs (`make setup` does)."""


def display(remote: str) -> str:
    """`remote` without user name or password, for messages and logs."""
    parts = urlsplit(remote)
    if not parts.scheme or "@" not in parts.netloc:
        return remote
    host = parts.netloc.rsplit("@", 1)[1]
    return urlunsplit((parts.scheme, host, parts.path, parts.query, ""))


def read_only(remote: str) -> bool:
    """Whether `remote` can only be read (a plain web server)."""
    return urlsplit(remote).scheme in ("http", "https")


def _scrub(text: str, remote: str) -> str:
    """`text` with the remote's user-info removed (libraries echo URLs in errors)."""
    userinfo = urlsplit(remote).netloc.rpartition("@")[0]
    if userinfo:
        text = text.replace(userinfo, "***")
    return re.sub(r"\s+", " ", text)[:200]


def open_remote(remote: str) -> tuple[Any, str]:
    """The fsspec filesystem and root path of `remote` (no trailing slash).

    Raises:
        StoreError: the scheme's library is not installed, or the URL is invalid.
    """
    import fsspec

    # sshfs takes the host (and optional user and port) from the URL; keys, agent and
    # known hosts come from ~/.ssh like the ssh command's.
    scheme = urlsplit(remote).scheme
    try:
        fs, root = fsspec.core.url_to_fs(remote)
    except ImportError as err:
        package = _EXTRAS.get(scheme, scheme)
        how = "'sonarmap[remotes]'" if scheme in _IN_EXTRA else package
        raise StoreError(
            f"remote {display(remote)}: needs {package}; install with `pip install {how}`"
        ) from err
    except (ValueError, OSError) as err:
        raise StoreError(f"remote {display(remote)}: {_scrub(str(err), remote)}") from err
    if scheme in ("http", "https"):
        return fs, remote.rstrip("/")
    return fs, str(root).rstrip("/")
