"""The recording layout sonarmap writes (navigation apart from the images) and what the
keyframes stage decompresses from it (issue 22): only the navigation's chunks and the
chunks of the keyframes' images; a chunk's CRC is checked when it is decompressed, and
`sonarmap topics` checks every chunk."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from test_readers_mcap import all_messages, write_synthetic
from typer.testing import CliRunner

import sonarmap.pipeline.readers.mcap_source as mcap_source
from sonarmap.pipeline.cli import app
from sonarmap.pipeline.readers import open_recording
from sonarmap.pipeline.readers.mcap_scan import _inner_records, decompress_chunk
from sonarmap.schemas.topics import SONAR_TOPIC, TOPIC_DEAD_RECKONING, TOPIC_GROUND_TRUTH
from sonarmap.stages.keyframes import STAGE, KeyframesConfig

# Synthetic odometry is ~0.7 kB and a synthetic sonar ping ~1.7 kB: 1 kB splits them, and
# 2 kB chunks hold about one image each (the simulator's layout, scaled down).
SMALL_BYTES, CHUNK_BYTES = 1000, 2000
NAV_TOPICS = {TOPIC_DEAD_RECKONING, TOPIC_GROUND_TRUTH, "/tf_static"}


def _chunk_messages(path: Path) -> dict[int, set[tuple[str, int]]]:
    """Chunk start offset -> (topic, log time) of the messages inside it, read straight
    from the chunk records (not through the message indexes the reader uses)."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        out = {}
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            data = decompress_chunk(Chunk.read(ReadDataStream(f)))
            out[index.chunk_start_offset] = {
                (summary.channels[r.channel_id].topic, r.log_time)
                for r in _inner_records(data)
                if isinstance(r, Message)
            }
        return out


def _chunk_topics(path: Path) -> dict[int, set[str]]:
    return {o: {topic for topic, _ in m} for o, m in _chunk_messages(path).items()}


@pytest.fixture(scope="module")
def split(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("layout") / "split.mcap"
    write_synthetic(
        path, n_pings=40, labels=False, chunk_size=CHUNK_BYTES, small_message_bytes=SMALL_BYTES
    )
    return path


def test_small_messages_are_chunked_apart_and_read_like_the_interleaved_file(
    split: Path, tmp_path: Path
) -> None:
    interleaved = tmp_path / "interleaved.mcap"
    write_synthetic(interleaved, n_pings=40, labels=False, chunk_size=CHUNK_BYTES)
    assert Counter(all_messages(split)) == Counter(all_messages(interleaved))
    chunks = _chunk_topics(split)
    nav_chunks = [topics for topics in chunks.values() if topics & NAV_TOPICS]
    assert nav_chunks and all(topics <= NAV_TOPICS for topics in nav_chunks)
    assert any(
        topics & NAV_TOPICS and len(topics) > 1 for topics in _chunk_topics(interleaved).values()
    )
    # Overlapping chunks come out in log-time order, as from the interleaved file.
    a, b = open_recording(split).source, open_recording(interleaved).source
    topics = [t.topic for t in a.topics()]
    assert [(n, t) for n, t, _ in a.messages(topics)] == [(n, t) for n, t, _ in b.messages(topics)]


def _run_stage(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[dict[str, Any], int]:
    """The keyframes stage with its frames consumed; (outputs, chunks decompressed)."""
    calls = []
    real = mcap_source.decompress_chunk

    def counting(chunk: Chunk) -> bytes:
        calls.append(chunk.uncompressed_size)
        return real(chunk)

    with monkeypatch.context() as m:
        m.setattr(mcap_source, "decompress_chunk", counting)
        cfg = KeyframesConfig(spacing_m=2.0)
        out = STAGE.run(cfg, {"dataset": open_recording(path, cfg)})
        out["frames"] = list(out["frames"])
    return out, len(calls)


def _read_pings(out: dict[str, Any]) -> set[int]:
    """The ping times a keyframes run decodes: its keyframes' and its calibration pairs'."""
    table = out["keyframes"]
    kept = set(table.column("t_ns").to_pylist()) | set(table.column("t_vertical_ns").to_pylist())
    for f in out["calibration_frames"]:
        kept |= {f.horizontal.t_ns, f.vertical.t_ns}
    return kept


def test_keyframes_decompress_only_navigation_and_the_keyframes_images(
    split: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out, n_decompressed = _run_stage(split, monkeypatch)
    table = out["keyframes"]
    assert 2 <= table.num_rows < out["sensors"]["pairing"]["pairs"] / 2
    pings = {(SONAR_TOPIC["horizontal"], t) for t in table.column("t_ns").to_pylist()}
    pings |= {(SONAR_TOPIC["vertical"], t) for t in table.column("t_vertical_ns").to_pylist()}
    chunks = _chunk_messages(split)
    n_nav = sum(1 for m in chunks.values() if {t for t, _ in m} & NAV_TOPICS)
    images = [m for m in chunks.values() if not {t for t, _ in m} & NAV_TOPICS]
    needed = [m for m in images if m & pings]
    # Each needed chunk once (the reader caches the last few), and no other.
    assert n_decompressed == n_nav + len(needed)
    assert len(needed) < len(images) / 2


def _with_bad_crc(path: Path, chunk_offset: int, out: Path) -> Path:
    data = bytearray(path.read_bytes())
    data[chunk_offset + 9 + 8 + 8 + 8] ^= 0xFF  # opcode, length, start, end, size, *crc*
    out.write_bytes(bytes(data))
    return out


def _keyframes(res: Any) -> list[dict[str, Any]]:
    assert res.exit_code == 0, res.output
    art = Path(json.loads(res.stdout)["stages"][0]["path"])
    return pq.read_table(art / "keyframes.parquet").to_pylist()


def test_corrupt_chunk_is_reported_by_the_run_that_reads_it_and_by_topics_always(
    split: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out, _ = _run_stage(split, monkeypatch)
    kept = _read_pings(out)
    with split.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    start = {c.chunk_start_offset: c.message_start_time for c in summary.chunk_indexes}
    images = [o for o, topics in _chunk_topics(split).items() if not topics & NAV_TOPICS]
    unused = next(o for o in images if start[o] not in kept)
    used = next(o for o in images if start[o] in kept)
    runner = CliRunner()

    def run(path: Path) -> Any:
        args = ["run", str(path), "--until", "keyframes", "--store", str(tmp_path / "s")]
        return runner.invoke(app, [*args, "-q", "--json"])

    clean = _keyframes(run(split))
    bad_unused = _with_bad_crc(split, unused, tmp_path / "unused.mcap")
    bad_used = _with_bad_crc(split, used, tmp_path / "used.mcap")
    # A chunk no keyframe or calibration pair needs is never decompressed: the run is computed from intact
    # chunks only; `topics` checks every chunk and reports it.
    assert _keyframes(run(bad_unused)) == clean
    for path, chunk in ((bad_unused, unused), (bad_used, used)):
        res = runner.invoke(app, ["topics", str(path), "--json"])
        assert res.exit_code == 2
        assert f"{path}: corrupt MCAP chunk at byte offset {chunk}: CRC mismatch" in res.stderr
    res = run(bad_used)
    assert res.exit_code == 2
    assert f"{bad_used}: corrupt MCAP chunk at byte offset {used}: CRC mismatch" in res.stderr
