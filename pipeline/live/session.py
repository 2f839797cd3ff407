"""The live view as the CLI uses it: start the server, print its address, chain the
feed into the runner's `on_stage`, and keep serving after the run until Ctrl-C."""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from typing import Any

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "LiveSession", "check_port", "live_session"]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


class LiveSession:
    """A started live view (or, disabled, a no-op with the same methods)."""

    def __init__(self, feed: Any | None) -> None:
        self.feed = feed

    def chain(self, on_stage: Callable[[Any], None]) -> Callable[[Any], None]:
        """`on_stage` that also publishes the finished stage."""
        feed = self.feed
        if feed is None:
            return on_stage

        def both(result: Any) -> None:
            on_stage(result)
            feed.on_stage(result)

        return both

    def serve_until_interrupted(self, stop: threading.Event | None = None) -> None:
        """Keep the server up (Foxglove can still connect) until Ctrl-C or `stop`."""
        if self.feed is None:
            return
        self.feed.server.drain()
        print(f"live: serving {self.feed.server.url} until Ctrl-C", file=sys.stderr, flush=True)
        stop = stop or threading.Event()
        with suppress(KeyboardInterrupt):
            while not stop.wait(0.5):  # short waits: Ctrl-C is seen between them
                pass


def check_port(port: int, option: str) -> None:
    """ConfigError (exit 2) naming `option` unless 0 <= port <= 65535."""
    if not 0 <= port <= 65535:
        from sonarmap.pipeline.engine.errors import ConfigError

        raise ConfigError(f"{option} {port}: a port is 0 (any free one) to 65535")


@contextmanager
def live_session(
    enabled: bool,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    linger: bool = True,
    option: str = "--live-port",
) -> Iterator[LiveSession]:
    """Start the live server when `enabled` and print `live: ws://HOST:PORT` on stderr;
    when the block ends without an error and `linger`, keep serving until Ctrl-C.
    `option` names the port in the error for one out of range."""
    if not enabled:
        yield LiveSession(None)
        return
    check_port(port, option)
    from sonarmap.pipeline.graph import pipeline_stages
    from sonarmap.pipeline.live.feed import LiveFeed
    from sonarmap.pipeline.live.server import LiveServer

    server = LiveServer(host, port)
    try:
        print(
            f"live: {server.url} (Foxglove: Open connection, Foxglove WebSocket)",
            file=sys.stderr,
            flush=True,
        )
        session = LiveSession(LiveFeed(server, pipeline_stages()))
        yield session
        if linger:
            session.serve_until_interrupted()  # only after a run that ended well
    finally:
        server.stop()
