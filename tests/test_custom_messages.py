"""Custom ROS 2 message types: a sqlite bag carries no definitions, so a driver's own type
is read only once its `.msg` / `.idl` files are given (config or `topics --msg`)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.readers import ReaderOptions, open_source
from sonarmap.stages.keyframes import KeyframesConfig

STAMPED = "oculus_interfaces/msg/OculusStampedPing"
PING = "oculus_interfaces/msg/Ping"
DEPTH = "my_vehicle/msg/Depth"
PING_MSG = "uint32 ping_id\nfloat64 range_resolution\nint16[] bearings\nuint8[] data\n"
STAMPED_MSG = "std_msgs/Header header\noculus_interfaces/Ping ping\n"
DEPTH_IDL = """
module my_vehicle {
  module msg {
    struct Depth {
      double depth;
      float pressure_pa;
    };
  };
};
"""


def _definitions(root: Path) -> list[Path]:
    msg_dir = root / "oculus_interfaces" / "msg"
    msg_dir.mkdir(parents=True)
    (msg_dir / "Ping.msg").write_text(PING_MSG)
    (msg_dir / "OculusStampedPing.msg").write_text(STAMPED_MSG)
    (root / "depth.idl").write_text(DEPTH_IDL)
    return [msg_dir / "Ping.msg", msg_dir / "OculusStampedPing.msg", root / "depth.idl"]


def _write_bag(path: Path) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(PING_MSG, PING))
    store.register(get_types_from_msg(STAMPED_MSG, STAMPED))
    store.register(get_types_from_idl(DEPTH_IDL))
    T = store.types
    with Writer(path, version=8) as bag:
        ping = bag.add_connection("/oculus/ping", STAMPED, typestore=store)
        depth = bag.add_connection("/depth", DEPTH, typestore=store)
        for k in range(3):
            t_ns = 1_000_000_000 + k * 100_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=1, nanosec=k * 100_000_000)
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="m750d")
            body = T[PING](
                ping_id=k,
                range_resolution=0.05,
                bearings=np.array([-6500, 0, 6500], np.int16),
                data=np.arange(6, dtype=np.uint8) + k,
            )
            msg = T[STAMPED](header=header, ping=body)
            bag.write(ping, t_ns, store.serialize_cdr(msg, STAMPED))
            d = T[DEPTH](depth=2.0 + k, pressure_pa=np.float32(101325.0))
            bag.write(depth, t_ns, store.serialize_cdr(d, DEPTH))


def test_custom_types_are_read_once_their_definitions_are_given(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bag = tmp_path / "dive"
    _write_bag(bag)
    defs = _definitions(tmp_path / "defs")
    plain = open_source(bag)
    assert {t.topic: (t.msgtype, t.count) for t in plain.topics()} == {
        "/oculus/ping": (STAMPED, 3),
        "/depth": (DEPTH, 3),
    }
    with caplog.at_level(logging.WARNING):
        assert list(plain.messages(["/oculus/ping"])) == []
    assert STAMPED in caplog.text and "message_definitions" in caplog.text
    src = open_source(bag, [str(d) for d in defs])
    pings = list(src.messages(["/oculus/ping"]))
    assert [m.ping.ping_id for _, _, m in pings] == [0, 1, 2]
    assert pings[2][2].header.frame_id == "m750d"
    np.testing.assert_array_equal(pings[2][2].ping.bearings, [-6500, 0, 6500])
    np.testing.assert_array_equal(pings[1][2].ping.data, np.arange(6) + 1)
    depths = [m.depth for _, _, m in src.messages(["/depth"])]
    assert depths == [2.0, 3.0, 4.0]
    # The same through the keyframes config, as `run` and `convert` take it.
    config = KeyframesConfig(message_definitions=[str(d) for d in defs])
    opts = ReaderOptions.from_config(config)
    assert len(list(open_source(bag, opts.message_definitions).messages(["/depth"]))) == 3


def test_topics_takes_msg_files_and_refuses_bad_ones_in_one_line(tmp_path: Path) -> None:
    bag = tmp_path / "dive"
    _write_bag(bag)
    defs = _definitions(tmp_path / "defs")
    args = ["topics", str(bag), "--json"]
    # In any order: OculusStampedPing.msg uses Ping, given after it here.
    given = [defs[1], defs[0], defs[2]]
    res = CliRunner().invoke(app, [*args, *(x for d in given for x in ("--msg", str(d)))])
    assert res.exit_code == 0, res.output
    assert {t["topic"]: t["count"] for t in json.loads(res.stdout)["topics"]} == {
        "/depth": 3,
        "/oculus/ping": 3,
    }
    bad = tmp_path / "bad" / "pkg" / "msg" / "Bad.msg"
    bad.parent.mkdir(parents=True)
    bad.write_text("uint32 ok\nthis is not a field definition\n")
    loose = tmp_path / "Loose.msg"
    loose.write_text(PING_MSG)
    typo = tmp_path / "typo" / "pkg" / "msg" / "Typo.msg"
    typo.parent.mkdir(parents=True)
    typo.write_text("uint32 ok\nflaot64 depth\n")
    broken = tmp_path / "broken" / "pkg" / "msg" / "Broken.msg"
    broken.parent.mkdir(parents=True)
    broken.write_text("float64[ x\n")
    for path, what in (
        (broken, "not a valid ROS 2 .msg definition"),
        (bad, "field is has type pkg/msg/this"),
        (typo, "field depth has type pkg/msg/flaot64, neither a standard ROS 2 type"),
        (loose, "a .msg file's type is its path"),
        (tmp_path / "missing.msg", "cannot read message definition"),
        (tmp_path / "defs.txt", "a message definition is a .msg or .idl file"),
    ):
        res = CliRunner().invoke(app, [*args, "--msg", str(path)])
        assert res.exit_code == 2, res.output
        [line] = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
        assert str(path) in line and what in line and "Traceback" not in res.output
    with pytest.raises(ConfigError, match=r"Bad\.msg"):
        open_source(bag, [bad])
