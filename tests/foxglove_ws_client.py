"""A minimal Foxglove WebSocket protocol (foxglove.websocket.v1) client for the live-view
tests: advertise -> subscribe -> binary MessageData frames, decoded with the schemas."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
"""The protocol's names: foxglove-sdk 0.30 servers accept only the second, its newer name."""
MESSAGE_DATA = 0x01


@dataclass
class Received:
    """What a client saw: advertised channels and each topic's (arrival, log time, msg)."""

    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[float, int, Any]]] = field(default_factory=dict)


def _decoder(channel: dict[str, Any]) -> Any:
    import base64

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


async def collect(
    url: str, until: Any, timeout_s: float = 60.0, on_subscribed: Any = None
) -> Received:
    """Connect, subscribe to every advertised channel (then call `on_subscribed()`),
    decode messages until `until(received)` is true (or the timeout)."""
    import websockets

    got = Received()
    decoders: dict[int, Any] = {}
    by_sub: dict[int, dict[str, Any]] = {}
    deadline = time.monotonic() + timeout_s
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        while time.monotonic() < deadline and not until(got):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    got.server_info = msg
                elif msg["op"] == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        got.channels[ch["id"]] = ch
                        sub_id = len(by_sub) + 1
                        by_sub[sub_id] = ch
                        decoders[sub_id] = _decoder(ch)
                        subs.append({"id": sub_id, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    if on_subscribed is not None:
                        on_subscribed()
                        on_subscribed = None
                continue
            if frame[0] != MESSAGE_DATA:
                continue
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            topic = by_sub[sub_id]["topic"]
            message = decoders[sub_id].FromString(frame[13:])
            got.messages.setdefault(topic, []).append((time.monotonic(), log_time, message))
    return got
