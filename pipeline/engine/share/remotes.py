"""Remotes as fsspec filesystems: local paths, `s3://`, `ssh://`/`sftp://`, `http(s)://`.

Credentials come from the places each library already reads (AWS environment and
config files for s3fs; ssh config, agent and keys for sshfs/asyncssh); sonarmap never
stores them. A URL may still carry a password (`sftp://user:secret@host/...`), so every
message names a remote through `display`, which drops the user-info part.
"""

from __future__ import annotations

import os
import re
import warnings
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from sonarmap.pipeline.engine.errors import ConfigError, StoreError

__all__ = [
    "check_bucket",
    "deadline",
    "display",
    "http_timeout",
    "open_remote",
    "read_only",
    "remote_failure",
    "remote_timeout_s",
    "request_deadline_s",
]

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


TIMEOUT_ENV = "SONARMAP_REMOTE_TIMEOUT_S"
DEFAULT_TIMEOUT_S = 15.0
"""Connect and read timeout of every remote request [s]: a server that accepts and never
answers fails a command in seconds (aiohttp's default is 5 minutes per request)."""


def remote_timeout_s() -> float:
    """The remote timeout [s], from `SONARMAP_REMOTE_TIMEOUT_S` or the default.

    Raises:
        ConfigError: the variable is set but not a number of seconds in (0, 3600].
    """
    raw = os.environ.get(TIMEOUT_ENV, "").strip()
    if not raw:
        return DEFAULT_TIMEOUT_S
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not 0 < value <= 3600:  # NaN fails too
        raise ConfigError(f"{TIMEOUT_ENV}={raw[:20]!r}: expected seconds, over 0 and at most 3600")
    return value


DEADLINE_FACTOR = 4
"""An http request (listing page, manifest, HEAD) must be done within this many timeouts
in all: the read timeout restarts with every byte, so a server that trickles bytes would
otherwise hold a command for good."""

MIN_RATE_BPS = 64 << 10
"""Slowest download accepted [bytes/s]: a file's request may take the request deadline
plus its declared size at this rate, and no longer."""


def request_deadline_s(nbytes: int = 0) -> float:
    """How long one http request moving `nbytes` may take in all [s]."""
    return DEADLINE_FACTOR * remote_timeout_s() + nbytes / MIN_RATE_BPS


def deadline(fs: Any, nbytes: int = 0) -> dict[str, float]:
    """Keyword arguments that bound one call on `fs` by `request_deadline_s(nbytes)`.

    Library timeouts bound a wait for a reply; a link that goes quiet while a request is
    being sent, or a server that accepts and then reads nothing, is covered by none of them.
    fsspec's sync wrapper of an async filesystem (s3fs, sshfs, http) takes `timeout` as a
    deadline for the whole call; other filesystems (local) take no such argument."""
    return {"timeout": request_deadline_s(nbytes)} if getattr(fs, "async_impl", False) else {}


def http_timeout(nbytes: int = 0) -> Any:
    """aiohttp's timeouts for a request moving `nbytes`: connect and read waits, and an
    overall deadline (`request_deadline_s`)."""
    import aiohttp

    t = remote_timeout_s()
    return aiohttp.ClientTimeout(
        total=request_deadline_s(nbytes), connect=t, sock_connect=t, sock_read=t
    )


def _timeouts(scheme: str) -> dict[str, Any]:
    """Storage options that bound each library's connect and read waits."""
    t = remote_timeout_s()
    if scheme in ("http", "https"):
        return {"client_kwargs": {"timeout": http_timeout()}}
    if scheme in ("s3", "s3a"):
        return {"config_kwargs": {"connect_timeout": t, "read_timeout": t,
                                  "retries": {"max_attempts": 2, "mode": "standard"}}}  # fmt: skip
    if scheme in ("ssh", "sftp"):
        return {"connect_timeout": t, "login_timeout": t}
    return {}


def remote_failure(err: BaseException, remote: str, operation: str) -> StoreError:
    """One line naming the remote, the operation and the cause (denied, not found, timed
    out, connection dropped, redirect loop) of a library's error, credentials scrubbed."""
    cause = "failed"
    seen: set[int] = set()
    current: BaseException | None = err
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        found = _cause(current)
        if found:
            cause = found
            break
        current = current.__cause__ or current.__context__
    detail = _scrub(f"{type(err).__name__}: {err}", remote)
    return StoreError(f"remote {display(remote)}: {operation}: {cause} ({detail})")


_CAUSES: tuple[tuple[tuple[str, ...], str], ...] = (
    (("TooManyRedirects",), "too many redirects (a redirect loop)"),
    (("PermissionError", "AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch",
      "NoCredentialsError", "PermissionDenied"), "access denied (check the credentials)"),
    (("FileNotFoundError", "NoSuchBucket", "NoSuchKey"), "not found"),
    (("TimeoutError", "ReadTimeoutError", "ConnectTimeoutError", "ServerTimeoutError",
      "ConnectionTimeoutError", "SocketTimeoutError"), "timed out"),
    (("ConnectionError", "EndpointConnectionError", "ClientConnectorError",
      "ServerDisconnectedError", "ClientOSError", "ConnectionResetError", "BrokenPipeError",
      "ConnectionRefusedError", "ClientPayloadError", "ConnectionLost"), "connection dropped"),
    (("ParamValidationError", "InvalidBucketName"), "invalid request"),
)  # fmt: skip


_AWS_CODES = ("AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch", "NoSuchBucket")
"""S3 error codes, found in the text of the error s3fs or botocore raises."""


def _cause(err: BaseException) -> str | None:
    names = {c.__name__ for c in type(err).__mro__}
    text = str(err)
    names |= {code for code in _AWS_CODES if code in text}
    for keys, cause in _CAUSES:
        if names & set(keys):
            if cause == "timed out":
                return (
                    f"timed out (no answer within {remote_timeout_s():g} s, or a request "
                    f"not done within {request_deadline_s():g} s)"
                )
            return cause
    return None


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
        with warnings.catch_warnings():
            # asyncssh (sshfs) uses algorithms cryptography deprecates: ten lines of its
            # warnings came before every sftp command's own output (`-v` does not need them).
            warnings.filterwarnings("ignore", module=r"asyncssh")
            fs, root = fsspec.core.url_to_fs(remote, **_timeouts(scheme))
    except ImportError as err:
        package = _EXTRAS.get(scheme, scheme)
        how = "'sonarmap[remotes]'" if scheme in _IN_EXTRA else package
        raise StoreError(
            f"remote {display(remote)}: needs {package}; install with `pip install {how}`"
        ) from err
    except OSError as err:  # sshfs connects here: the same cause words as a transfer's
        cause = _cause(err) or "cannot connect"
        detail = _scrub(f"{type(err).__name__}: {err}", remote)
        raise StoreError(f"remote {display(remote)}: {cause} ({detail})") from err
    except ValueError as err:
        raise StoreError(f"remote {display(remote)}: {_scrub(str(err), remote)}") from err
    if scheme in ("s3", "s3a"):
        fs.retries = 2  # s3fs retries a timeout 5 times with back-off: minutes, not seconds
    if scheme in ("http", "https"):
        return fs, remote.rstrip("/")
    return fs, str(root).rstrip("/")


def check_bucket(fs: Any, root: str, remote: str, create: bool) -> None:
    """Refuse a destination that does not exist unless `create`: a bucket (an object store
    would create one on the first write, under whatever name a typo gave), or a folder on
    a disk or an sftp server (a typo in a path would grow a new tree there)."""
    protocol = fs.protocol if isinstance(fs.protocol, str) else fs.protocol[0]
    if protocol not in ("s3", "s3a", "gs", "gcs"):
        _check_folder(fs, root, remote, create)
        return
    bucket = root.split("/", 1)[0]
    if protocol in ("s3", "s3a"):
        # Not `exists`: s3fs answers False for an endpoint it cannot reach as well.
        try:
            fs.call_s3("head_bucket", Bucket=bucket)
            return
        except FileNotFoundError:
            pass
    elif fs.exists(bucket):
        return
    shown = _scrub(bucket, remote)  # a URL's user-info may have been parsed into it
    if not create:
        raise StoreError(
            f"remote {display(remote)}: push: bucket {shown!r} does not exist (pass --create "
            "to create it)"
        )
    fs.mkdir(bucket)


def _check_folder(fs: Any, root: str, remote: str, create: bool) -> None:
    if fs.isdir(root):
        return
    shown = _scrub(root, remote)[:120]
    if fs.exists(root):
        raise StoreError(f"remote {display(remote)}: push: {shown!r} is not a folder")
    if not create:
        raise StoreError(
            f"remote {display(remote)}: push: folder {shown!r} does not exist (pass --create "
            "to create it)"
        )
    fs.makedirs(root, exist_ok=True)
