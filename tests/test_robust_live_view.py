"""Warnings are warnings (issue 52, root 7): the live view's SDK reporting a client that
went away ("Error sending message to client ... Broken pipe") prints a `warning:` line,
never an `error:` one; the server goes on serving."""

from __future__ import annotations

import io
import logging

import pytest

from sonarmap.pipeline.cli import _UserFormatter
from sonarmap.pipeline.live.server import LiveServer

pytest.importorskip("foxglove")


@pytest.mark.parametrize(
    "name", ["foxglove.websocket.connected_client", "foxglove.websocket.server"]
)
def test_a_client_that_disconnects_is_a_warning_line(name: str) -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(_UserFormatter(detailed=False))
    root = logging.getLogger()
    root.addHandler(handler)
    server = LiveServer(port=0)
    try:
        logging.getLogger(name).error(
            "Error sending message to client 127.0.0.1:50522: IO error: Broken pipe (os error 32)"
        )
        logging.getLogger("sonarmap.other").error("a real error")
    finally:
        server.stop()
        root.removeHandler(handler)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("warning: live view: Error sending message to client"), lines
    assert lines[1] == "error: a real error"
