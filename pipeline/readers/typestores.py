"""Deserialisation of ROS 2 CDR messages with rosbags, for types known or embedded."""

from __future__ import annotations

import logging
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.formats.rosmsg import custom_msg_texts, ros2_typestore
from pipeline.readers.sonar_decode import ProjectedArrays

__all__ = ["Ros2Decoder"]

log = logging.getLogger(__name__)
_PROJECTED = "marine_acoustic_msgs/msg/ProjectedSonarImage"


class Ros2Decoder:
    """CDR -> rosbags message objects; unknown types are registered from embedded schemas.

    A type that cannot be parsed (e.g. a service event) is skipped with one warning.
    """

    def __init__(self, schemas: dict[str, tuple[str, str]] | None = None) -> None:
        self._schemas = schemas or {}
        self._store: Typestore = ros2_typestore()
        self._private = False
        self._bad: set[str] = set()

    def _ensure(self, msgtype: str) -> bool:
        if msgtype in self._store.types:
            return True
        if msgtype in self._bad:
            return False
        encoding, text = self._schemas.get(msgtype, ("", ""))
        try:
            if encoding != "ros2msg" or not text:
                raise ValueError("no ros2msg schema embedded")
            types = get_types_from_msg(text, msgtype)
            if not self._private:
                store = get_typestore(Stores.ROS2_HUMBLE)
                for name, txt in custom_msg_texts().items():
                    store.register(get_types_from_msg(txt, name))
                self._store, self._private = store, True
            self._store.register({k: v for k, v in types.items() if k not in self._store.types})
        except Exception as err:
            self._bad.add(msgtype)
            log.warning("cannot decode messages of type %s (%s); skipped", msgtype, err)
            return False
        return msgtype in self._store.types

    def knows(self, msgtype: str) -> bool:
        """Whether messages of this type can be decoded."""
        return self._ensure(msgtype)

    def decode(self, data: bytes | memoryview, msgtype: str, topic: str = "") -> Any | None:
        """Deserialise one message (None when its type is unknown or the bytes are bad)."""
        if msgtype == _PROJECTED:
            try:
                return ProjectedArrays.from_cdr(data)
            except (ValueError, IndexError, TypeError):
                pass  # big-endian or unusual: the generic path below
        if not self._ensure(msgtype):
            return None
        try:
            return self._store.deserialize_cdr(bytes(data), msgtype)
        except Exception as err:
            log.warning("topic %s: undecodable %s message (%s); skipped", topic, msgtype, err)
            return None
