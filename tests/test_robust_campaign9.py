"""Campaign 9 (the live view and `status`): each test failed on the code before its fix."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.live.preview import unsaid
from sonarmap.stages.evaluate.foxglove_scene import preview_messages
from tests.fixtures.recordings import small_recording


def test_the_preview_cloud_is_stamped_at_its_log_time() -> None:
    """The cloud's header said its newest keyframe (0 when empty), the log time another."""
    keyframes = pa.table(
        {
            "keyframe_id": pa.array([], pa.int64()), "t_ns": pa.array([], pa.int64()),
            **{c: pa.array([], pa.float64()) for c in
               ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")},
        }
    )  # fmt: skip
    fused = pa.table({c: pa.array([], pa.float64()) for c in ("x_m", "y_m", "z_m")}).append_column(
        "keyframe_id", pa.array([], pa.int64())
    )
    t = 1_700_000_000_500_000_000
    cloud, poses = preview_messages(fused, keyframes, np.eye(4), t)
    assert cloud.log_time_ns == poses.log_time_ns == t
    assert _stamp_ns(cloud.message.encode()) == t


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        value |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if byte < 0x80:
            return value, i


def _stamp_ns(encoded: bytes) -> int:
    """foxglove.PointCloud's field 1 (timestamp: seconds, nanos), read off the wire."""
    tag, i = _varint(encoded, 0)
    assert tag == (1 << 3) | 2, tag  # field 1, length-delimited
    size, i = _varint(encoded, i)
    fields, j = {}, i
    while j < i + size:
        key, j = _varint(encoded, j)
        fields[key >> 3], j = _varint(encoded, j)
    return fields.get(1, 0) * 1_000_000_000 + fields.get(2, 0)


def test_the_previews_window_warnings_are_not_printed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    window = tmp_path / "sonarmap-follow-x" / "window.mcap"
    log = logging.getLogger("sonarmap.pipeline.readers.recording")
    with caplog.at_level(logging.WARNING), unsaid(window):
        log.warning("%s: 1 of 14 horizontal pings fall outside the navigation's span", window)
        log.warning("another file: kept")
    log.warning("%s: after the preview's read, said again", window)
    said = [r.getMessage() for r in caplog.records]
    assert said == ["another file: kept", f"{window}: after the preview's read, said again"]


def test_status_on_a_store_that_is_not_there_creates_none(tmp_path: Path) -> None:
    typo = tmp_path / "stroe"
    rows = _status(_recording(tmp_path), typo)
    assert rows["keyframes"]["status"] == "miss"
    assert not typo.exists()


def test_a_beam_table_file_enters_the_keys_by_its_content(tmp_path: Path) -> None:
    """An edited beam-table file kept every key: stale sensors.json and metrics were
    served as hits, and the recording-facts unit too (campaign 11 #1)."""
    table = tmp_path / "hs.yaml"

    def key() -> str:
        rows = _status(
            _recording(tmp_path), tmp_path / "store",
            "--set", f"keyframes.horizontal_sonar={table}", "--until", "keyframes",
        )  # fmt: skip
        return rows["keyframes"]["key"]

    table.write_text("fov_deg: 130.0\nvertical_aperture_deg: 20.0\nmax_range_m: 120.0\n")
    first = key()
    table.write_text("fov_deg: 60.0\nvertical_aperture_deg: 8.0\nmax_range_m: 30.0\n")
    assert key() != first
    table.write_text("fov_deg: 130.0\nvertical_aperture_deg: 20.0\nmax_range_m: 120.0\n")
    assert key() == first
    # No file named: the default config's keys are those of before the field.
    from sonarmap.stages.keyframes.config import KeyframesConfig

    assert "files_sha256" not in KeyframesConfig().model_dump(mode="json")


def _recording(tmp_path: Path) -> Path:
    return small_recording(tmp_path / "rec.mcap", duration_s=8.0)


def _status(recording: Path, store: Path, *extra: str) -> dict[str, dict[str, str]]:
    res = CliRunner().invoke(
        app, ["status", str(recording), "--store", str(store), "--json", *extra]
    )
    assert res.exit_code == 0, res.output
    return {r["stage"]: r for r in json.loads(res.stdout)["stages"]}
