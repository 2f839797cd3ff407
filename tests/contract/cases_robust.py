"""Issue 52's cases (robustness, third round): field clocks in every bag format, a raw
Oculus capture that claims more than memory holds, user files that are not files, COCO
files of the wrong shape, remotes that never answer, trickle, loop or are missing.

Each prepares its input in the case's work directory (servers: threads on 127.0.0.1 that
live as long as the campaign); the contract then checks the exit code, one `error:` line,
RSS within 1 GB and time within 10 s."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from tests.contract.case import Case, names
from tests.fixtures.hostile_http import started_server
from tests.fixtures.ingest import odometry

S = 1_000_000_000
T0 = 1_700_000_000 * S
NAV = "/odometry/dead_reckoning"
ODOM = "nav_msgs/msg/Odometry"
SECRET = "sEcReT52robust"


# -- field clocks ------------------------------------------------------------------------


def _set_back() -> list[tuple[int, float]]:
    """(t_ns, x) of a navigation clock run 0..12 s, then set back 8 s at another place."""
    first = [(T0 + int(k * 0.1 * S), 0.05 * k) for k in range(121)]
    return first + [(T0 + int((4.1 + k * 0.1) * S), 100.0) for k in range(60)]


def _bag1_set_back(work: Path) -> list[str]:
    from rosbags.rosbag1 import Writer

    from sonarmap.pipeline.formats.rosmsg import ros1_typestore

    store = ros1_typestore()
    with Writer(work / "d.bag") as bag:
        conn = bag.add_connection(NAV, ODOM, typestore=store)
        for t, x in _set_back():
            bag.write(conn, t, store.serialize_ros1(odometry(t, (x, 0.0, 0.0), ros1=True), ODOM))
    return ["topics", "d.bag"]


def _sqlite_set_back(work: Path) -> list[str]:
    from rosbags.rosbag2 import Writer

    from sonarmap.pipeline.formats.rosmsg import ros2_typestore

    store = ros2_typestore()
    with Writer(work / "dive", version=8) as bag:
        conn = bag.add_connection(NAV, ODOM, typestore=store)
        for t, x in _set_back():
            bag.write(conn, t, store.serialize_cdr(odometry(t, (x, 0.0, 0.0)), ODOM))
    return ["topics", "dive"]


def _mcap_set_back(work: Path) -> list[str]:
    from sonarmap.pipeline.formats.rosmsg import Ros2McapWriter

    with (work / "d.mcap").open("wb") as f, Ros2McapWriter(f) as w:
        for t, x in _set_back():
            w.write(NAV, ODOM, odometry(t, (x, 0.0, 0.0)), t)
    return ["topics", "d.mcap"]


def _warns(text: str) -> Any:
    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        out = done.stdout + done.stderr
        return None if text in out else f"no warning with {text!r}"

    return check


# -- raw Oculus captures -----------------------------------------------------------------


def _oculus_ping(n_ranges: int = 40, n_beams: int = 16) -> bytes:
    from sonarmap.pipeline.readers.oculus_raw import _PING

    head = np.zeros(1, _PING)
    offset = _PING.itemsize + 2 * n_beams
    size = offset + n_ranges * n_beams
    h = head[0]
    h["head"]["oculus_id"], h["head"]["msg_id"], h["head"]["version"] = 0x4F53, 0x23, 1
    h["head"]["payload_size"] = size - 16
    h["range"], h["range_resolution"], h["frequency"] = 10.0, 0.05, 1.2e6
    h["n_ranges"], h["n_beams"], h["image_offset"], h["image_size"] = (
        n_ranges,
        n_beams,
        offset,
        n_ranges * n_beams,
    )
    bearings = np.linspace(-3000, 3000, n_beams).astype("<i2")
    image = (np.arange(n_ranges * n_beams) % 251).astype(np.uint8)
    return head.tobytes() + bearings.tobytes() + image.tobytes()


def _oculus_sparse(work: Path) -> list[str]:
    """Three real pings, then 3 GiB of zeros (sparse: no disk used)."""
    with (work / "big.raw").open("wb") as f:
        f.write(_oculus_ping() * 3)
        f.truncate(3 << 30)
    return ["topics", "big.raw"]


def _oculus_claims_4gib(work: Path) -> list[str]:
    ping = bytearray(_oculus_ping())
    ping[10:14] = (0xFFFFFFF0).to_bytes(4, "little")
    (work / "huge.raw").write_bytes(bytes(ping))
    return ["topics", "huge.raw"]


# -- user files and labels ---------------------------------------------------------------


def _exported(work: Path) -> Path:
    """A COCO export of two keyframes (the package's own exporter)."""
    from sonarmap.pipeline.labels.files import export_labels
    from sonarmap.schemas.annotations import AnnotationFile
    from sonarmap.schemas.classes import CLASS_IDS
    from sonarmap.schemas.sonar import KeyframeImages, SonarPing

    ranges = np.linspace(1.0, 20.0, 200)
    angles = np.deg2rad(np.linspace(-65, 65, 64))

    def ping(t: int) -> SonarPing:
        return SonarPing(t, "horizontal", np.full((200, 64), 3, np.uint8), ranges, angles)

    frames = [KeyframeImages(k, t, ping(t), ping(t)) for k, t in enumerate([S, 2 * S])]
    labels = AnnotationFile.model_validate(
        {"keyframes": [{"t_ns": S, "objects": [{"class_name": "cylindrical_piling", "box_m": {
            "x_min_m": 5.4, "x_max_m": 6.3, "y_min_m": 2.5, "y_max_m": 3.4}}]}]}
    )  # fmt: skip
    (work / "d.mcap").write_bytes(b"a recording")
    shapes = {0: labels.keyframes[0].objects}
    done = export_labels(work / "d.mcap", work / "x", frames, {}, shapes, CLASS_IDS, 1.0)
    return done.coco


def _coco_edit(change: Any) -> Any:
    def build(work: Path) -> list[str]:
        coco = _exported(work)
        doc = json.loads(coco.read_text())
        change(doc)
        coco.write_text(json.dumps(doc))
        return ["label", "import", str(coco.relative_to(work)), "-o", "a.yaml"]

    return build


def _swapped(which: str, kind: str) -> Any:
    """An export whose COCO file or geometry.json is then a FIFO or /dev/zero."""

    def build(work: Path) -> list[str]:
        coco = _exported(work)
        target = coco if which == "coco" else coco.parent / "geometry.json"
        target.unlink()
        if kind == "fifo":
            os.mkfifo(target)
        else:
            target.symlink_to("/dev/zero")
        return ["label", "import", str(coco.relative_to(work)), "-o", "a.yaml"]

    return build


def _recording_blank(work: Path) -> list[str]:
    coco = _exported(work)
    geometry = coco.parent / "geometry.json"
    doc = json.loads(geometry.read_text())
    doc["recording"] = ""
    geometry.write_text(json.dumps(doc))
    return ["label", "import", str(coco.relative_to(work))]


def _nothing_hidden(work: Path, done: Any) -> str | None:
    hidden = [p.name for p in work.rglob(".*.yaml")]
    return f"wrote {hidden}" if hidden else None


def _existing_not_utf8(work: Path) -> list[str]:
    coco = _exported(work)
    (work / "a.yaml").write_bytes(b"\xff\xfe not utf-8 \x80")
    return ["label", "import", str(coco.relative_to(work)), "-o", "a.yaml"]


# -- remotes -----------------------------------------------------------------------------


def _pull_silent(work: Path) -> list[str]:
    return ["pull", f"http://127.0.0.1:{started_server('silent')}/lab"]


def _pull_trickle(work: Path) -> list[str]:
    return ["pull", f"http://127.0.0.1:{started_server('trickle')}/lab"]


def _pull_loop(work: Path) -> list[str]:
    return ["pull", f"http://127.0.0.1:{started_server('redirect_loop')}/lab"]


def _push_missing_folder(work: Path) -> list[str]:
    return ["push", "shraed/sonar"]


def _push_onto_file(work: Path) -> list[str]:
    (work / "remote").write_text("x")
    return ["push", "remote"]


def _push_secret_bad_bucket(work: Path) -> list[str]:
    return ["push", f"s3://AKIDKEY:{SECRET}@Bad_Bucket!!/x"]


def _says(text: str) -> Any:
    def check(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
        out = done.stdout + done.stderr
        if SECRET in out:
            return "the secret was printed"
        return None if text in out else f"no {text!r} in the output"

    return check


def _offline_s3(work_env: dict[str, str]) -> dict[str, str]:
    return {
        "AWS_ACCESS_KEY_ID": "x",
        "AWS_SECRET_ACCESS_KEY": "y",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL_S3": "http://127.0.0.1:9",
        "SONARMAP_REMOTE_TIMEOUT_S": "2",
        **work_env,
    }


QUICK = {"SONARMAP_REMOTE_TIMEOUT_S": "1"}

CASES: list[Case] = [
    Case("field navigation", "ROS 1 bag: navigation clock set back 8 s", _bag1_set_back, (0,),
         _warns("the clock runs backwards: dropped 60 of 181")),
    Case("field navigation", "rosbag2 sqlite: navigation clock set back 8 s", _sqlite_set_back,
         (0,), _warns("the clock runs backwards: dropped 60 of 181")),
    Case("field navigation", "MCAP: navigation clock set back 8 s", _mcap_set_back, (0,),
         _warns("the clock runs backwards: dropped 60 of 181")),
    Case("raw sonar files", "raw Oculus capture: 3 pings then 3 GiB of zeros", _oculus_sparse,
         (0,), _warns("trailing bytes unreadable")),
    Case("raw sonar files", "raw Oculus ping claiming 4 GiB", _oculus_claims_4gib,
         check=names("huge.raw", "over the limit of 256 MiB")),
    *(
        Case("labels", f"label import: {which} file is {what}", _swapped(which, kind),
             check=names("is not a regular file"))
        for which in ("coco", "geometry")
        for kind, what in (("fifo", "a FIFO"), ("dev-zero", "/dev/zero behind a symlink"))
    ),
    Case("labels", "label import: one category id twice (piling, then seawall)",
         _coco_edit(lambda d: d["categories"].append({"id": d["categories"][0]["id"],
                                                     "name": "seawall"})),
         check=names("categories[", "is also categories[")),
    Case("labels", 'label import: geometry.json says "recording": ""', _recording_blank,
         check=_nothing_hidden),
    Case("labels", "label import: an existing -o that is not UTF-8", _existing_not_utf8,
         check=names("a.yaml")),
    Case("labels", "label import: images is an int", _coco_edit(lambda d: d.update(images=5)),
         check=names("coco", "images: Input should be a valid list")),
    Case("labels", "label import: an image id is a list",
         _coco_edit(lambda d: d["images"][0].update(id=[1])), check=names("images[0].id")),
    Case("labels", "label import: duplicate image ids",
         _coco_edit(lambda d: d["images"][1].update(id=d["images"][0]["id"])),
         check=names("images[1].id", "is also images[0].id")),
    Case("sharing", "pull: an http server that never answers", _pull_silent,
         check=_says("pull: timed out"), env=QUICK),
    Case("sharing", "pull: an http server that trickles a byte every 0.3 s", _pull_trickle,
         check=_says("pull: timed out"), env=QUICK),
    Case("sharing", "pull: an http redirect loop", _pull_loop, check=_says("redirect loop")),
    Case("sharing", "push to a folder that does not exist", _push_missing_folder,
         check=_says("does not exist (pass --create")),
    Case("sharing", "push onto a path that is a file (no --create)", _push_onto_file,
         check=_says("is not a folder")),
    Case("sharing", "push s3://KEY:SECRET@ with a bucket name botocore rejects",
         _push_secret_bad_bucket, (1, 2), _says("remote s3://"), env=_offline_s3({})),
    Case("config", "a 10,000-character --set value (one line within 400 characters)",
         lambda work: ["convert", "x.mcap", "-o", "o.mcap", "--set", "x" * 10_000]),
]  # fmt: skip
