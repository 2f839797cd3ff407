"""The live view's WebSocket server (foxglove-sdk), with the latest messages of each
topic kept so that a client that subscribes late still sees the run so far.

Messages are built only when someone looks: a stage's messages are built when it
completes if a client is subscribed to one of its topics, else when one first
subscribes. A run with no client connected so pays only for the bookkeeping.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from foxglove.websocket import ServerListener

from sonarmap.pipeline.engine.errors import OutputError
from sonarmap.stages.evaluate.foxglove_scene import TOPIC_SCHEMAS, SceneMessage

__all__ = ["Builder", "ClientTrouble", "LiveServer", "quiet_client_errors"]

log = logging.getLogger(__name__)

Builder = Callable[[], Iterable[SceneMessage]]
"""Builds one stage's messages from its artifacts (run on the server's worker thread)."""

REPLAY_MAX = 200
"""Messages per topic kept for a client that subscribes late (the latest)."""
_SUBSCRIBE_WAIT_S = 2.0
"""How long a replay waits for the server to register a new subscription."""


class ClientTrouble(logging.Filter):
    """The SDK's errors about one client (a viewer closed mid-send: "Error sending message
    to client ... Broken pipe") become warnings: the run and the other clients go on, and
    a script watching for `error:` lines must not read a closed browser tab as a failure."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.name.startswith(_SDK_LOGGERS) and record.levelno >= logging.ERROR:
            record.levelno, record.levelname = logging.WARNING, "WARNING"
            record.msg = f"live view: {record.msg}"
        return True


_SDK_LOGGERS = ("foxglove.websocket", "foxglove.websocket_server")
"""Loggers (pyo3-log: the Rust module path, `::` as `.`) of the SDK's client connections."""


def quiet_client_errors() -> None:
    """Install `ClientTrouble` on the root logger's handlers (where the SDK's records
    end up; a filter on a parent logger would not see its children's records)."""
    for handler in logging.getLogger().handlers:
        if not any(isinstance(f, ClientTrouble) for f in handler.filters):
            handler.addFilter(ClientTrouble())


class LiveServer:
    """A Foxglove WebSocket server on `host:port` with a channel per `TOPIC_SCHEMAS` topic.

    `submit(topics, builder)` hands over a finished stage; a worker thread builds and
    logs its messages when (or once) a client subscribes to one of `topics`.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765) -> None:
        import foxglove
        import foxglove.messages

        quiet_client_errors()
        self._context = foxglove.Context()  # its own: only this server sees these channels
        self._channels = {
            topic: foxglove.Channel(
                topic,
                schema=getattr(foxglove.messages, name).get_schema(),
                message_encoding="protobuf",
                context=self._context,
            )
            for topic, name in TOPIC_SCHEMAS.items()
        }
        self._pending: dict[str, Builder] = {}  # topic -> builder not run yet
        self._latest: dict[str, list[tuple[bytes, int]]] = {}  # topic -> last messages
        self._lock = threading.Lock()
        self._jobs: queue.Queue[tuple[str, Any]] = queue.Queue()
        self._worker = threading.Thread(target=self._work, name="sonarmap-live", daemon=True)
        self._worker.start()
        try:
            self._server = foxglove.start_server(
                name="sonarmap",
                host=host,
                port=port,
                context=self._context,
                server_listener=_Listener(self._jobs),
            )
        except Exception as err:  # the SDK raises its own error types for bind failures
            self.stop()
            raise OutputError(
                f"live view: cannot listen on {host}:{port} ({str(err)[:120]})"
            ) from err
        self.host = host

    @property
    def port(self) -> int:
        """The port the server listens on (the one chosen when 0 was asked for)."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """`ws://host:port` for Foxglove's "Open connection"."""
        return f"ws://{self.host}:{self.port}"

    def submit(self, topics: Sequence[str], builder: Builder) -> None:
        """A stage finished: its messages (on `topics`) come from `builder`."""
        self._jobs.put(("stage", (tuple(topics), builder)))

    def drain(self, timeout_s: float = 30.0) -> bool:
        """Wait until the worker has handled everything submitted so far."""
        done = threading.Event()
        self._jobs.put(("mark", done))
        return done.wait(timeout_s)

    def stop(self) -> None:
        """Stop the worker and the server."""
        self._jobs.put(("stop", None))
        server = getattr(self, "_server", None)
        if server is not None:
            server.stop()

    def _work(self) -> None:
        while True:
            kind, item = self._jobs.get()
            try:
                if kind == "stop":
                    return
                if kind == "mark":
                    item.set()
                elif kind == "stage":
                    self._stage(*item)
                elif kind == "subscribe":
                    self._replay([item, *self._queued_subscriptions()])
            except Exception as err:  # a view must never take the run down with it
                log.warning("live view: %s not published (%s)", kind, str(err)[:200])

    def _stage(self, topics: tuple[str, ...], builder: Builder) -> None:
        if any(self._channels[t].has_sinks() for t in topics):
            self._publish(builder())
            return
        with self._lock:
            for t in topics:
                self._pending[t] = builder

    def _publish(self, messages: Iterable[SceneMessage]) -> None:
        batches: dict[str, deque[tuple[bytes, int]]] = {}
        for m in messages:  # logged as built: a long mission's images are never all held
            data = m.message.encode()
            batches.setdefault(m.topic, deque(maxlen=REPLAY_MAX)).append((data, m.log_time_ns))
            self._channels[m.topic].log(data, log_time=m.log_time_ns)
        with self._lock:
            for topic, batch in batches.items():
                self._latest[topic] = list(batch)
                self._pending.pop(topic, None)

    def _queued_subscriptions(self) -> list[str]:
        """The subscriptions queued right behind the one at hand (a client subscribes to
        every topic at once), taken off the queue to be served with it."""
        topics = []
        with self._jobs.mutex:
            waiting = self._jobs.queue
            while waiting and waiting[0][0] == "subscribe":
                topics.append(waiting.popleft()[1])
        return topics

    def _replay(self, topics: list[str]) -> None:
        """Serve new subscriptions: each stage whose messages wait for a subscriber is
        built once (a stage's builder logs all its topics: run per topic, the same
        subscriber got them again for each), the other topics get their latest messages
        (the other clients of a topic get those again)."""
        channels = [(t, self._channels[t]) for t in dict.fromkeys(topics) if t in self._channels]
        deadline = time.monotonic() + _SUBSCRIBE_WAIT_S
        while not all(c.has_sinks() for _, c in channels) and time.monotonic() < deadline:
            time.sleep(0.01)
        with self._lock:
            builders = {id(b): b for t, _ in channels if (b := self._pending.get(t)) is not None}
        published: set[str] = set()

        def noted(messages: Iterable[SceneMessage]) -> Iterator[SceneMessage]:
            for m in messages:  # still one at a time: a long mission's images never all held
                published.add(m.topic)
                yield m

        for builder in builders.values():
            self._publish(noted(builder()))
        for topic, channel in channels:
            if topic in published:
                continue
            with self._lock:
                latest = list(self._latest.get(topic, ()))
            for data, t in latest:
                channel.log(data, log_time=t)


class _Listener(ServerListener):
    """foxglove ServerListener: a subscription asks the worker to replay that topic."""

    def __init__(self, jobs: queue.Queue[tuple[str, Any]]) -> None:
        self._jobs = jobs

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self._jobs.put(("subscribe", channel.topic))
