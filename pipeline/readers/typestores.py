"""Deserialisation of ROS 2 CDR messages with rosbags, for types known, embedded in the
recording, or defined by the user's `.msg` / `.idl` files (`load_message_types`)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.formats.projected_cdr import ProjectedArrays
from sonarmap.pipeline.formats.rosmsg import custom_msg_texts, ros2_typestore

__all__ = ["Ros2Decoder", "load_message_types"]

log = logging.getLogger(__name__)
_PROJECTED = "marine_acoustic_msgs/msg/ProjectedSonarImage"


_MAX_DEFINITION_BYTES = 1 << 20


def _msg_type_name(path: Path) -> str:
    """`pkg/msg/Name` from a .msg path laid out as ROS packages are (.../pkg/msg/Name.msg)."""
    parts = path.with_suffix("").parts
    if len(parts) < 3 or parts[-2] != "msg" or not parts[-3]:
        raise ConfigError(
            f"{path}: a .msg file's type is its path: put it at <package>/msg/{path.stem}.msg"
        )
    return f"{parts[-3]}/msg/{parts[-1]}"


def load_message_types(paths: Sequence[str | Path]) -> dict[str, Any]:
    """The message types defined by `.msg` / `.idl` files, for `Ros2Decoder(extra_types=)`.

    A .msg file's type name comes from its path (`<package>/msg/<Name>.msg`); an .idl file
    names its own types.

    Raises:
        ConfigError: a file missing, too large, not UTF-8 or not a valid definition; one
            line naming it.
    """
    from sonarmap.pipeline.engine.config.yaml_files import _read_capped

    types: dict[str, Any] = {}
    loaded: list[tuple[Path, dict[str, Any]]] = []
    for item in paths:
        path = Path(item)
        suffix = path.suffix.lower()
        if suffix not in (".msg", ".idl"):
            raise ConfigError(f"{path}: a message definition is a .msg or .idl file")
        raw = _read_capped(path, "message definition", ConfigError, _MAX_DEFINITION_BYTES)
        try:
            text = raw.decode("utf-8")
            found = (
                get_types_from_msg(text, _msg_type_name(path))
                if suffix == ".msg"
                else get_types_from_idl(text)
            )
        except ConfigError:
            raise
        except Exception as err:  # rosbags raises its own parser errors
            detail = " ".join(str(err).split())[:160]
            raise ConfigError(f"{path}: not a valid ROS 2 {suffix} definition ({detail})") from err
        types.update(found)
        loaded.append((path, found))
    for path, found in loaded:  # after all: a file may use a type a later one defines
        _check_references(path, found, types)
    return types


def _check_references(path: Path, found: dict[str, Any], known: dict[str, Any]) -> None:
    """Refuse a definition whose fields name a type that is neither standard nor given
    (rosbags' parser reads any two words as `Type name`, so typos pass it)."""
    from rosbags.typesys.base import Nodetype

    store = ros2_typestore()

    def names(desc: Any) -> list[str]:
        kind, detail = desc
        if kind == Nodetype.NAME:
            return [str(detail)]
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return names(detail[0])
        return []

    for typename, (_, fields) in found.items():
        for field_name, desc in fields:
            for ref in names(desc):
                if ref not in store.types and ref not in known:
                    raise ConfigError(
                        f"{path}: {typename} field {field_name!s:.40} has type {ref:.80}, "
                        "neither a standard ROS 2 type nor defined in the given files"
                    )


class Ros2Decoder:
    """CDR -> rosbags message objects; unknown types are registered from embedded schemas.

    A type that cannot be parsed (e.g. a service event) is skipped with one warning.
    """

    def __init__(
        self,
        schemas: dict[str, tuple[str, str]] | None = None,
        extra_types: dict[str, Any] | None = None,
    ) -> None:
        self._schemas = schemas or {}
        self._store: Typestore = ros2_typestore()
        self._private = False
        self._bad: set[str] = set()
        if extra_types:
            self._private_store()
            self._store.register(
                {k: v for k, v in extra_types.items() if k not in self._store.types}
            )

    def _private_store(self) -> None:
        """Switch to a store of our own before registering types (the shared one is cached)."""
        if not self._private:
            store = get_typestore(Stores.ROS2_HUMBLE)
            for name, txt in custom_msg_texts().items():
                store.register(get_types_from_msg(txt, name))
            self._store, self._private = store, True

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
            self._private_store()
            self._store.register({k: v for k, v in types.items() if k not in self._store.types})
        except Exception as err:
            self._bad.add(msgtype)
            log.warning(
                "cannot decode messages of type %s (%s); skipped (give its .msg/.idl file as "
                "keyframes.message_definitions, or --msg)",
                msgtype,
                err,
            )
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
