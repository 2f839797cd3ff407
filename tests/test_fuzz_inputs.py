"""Fuzz suite for bad input files (issue 23): `topics`, `convert` and `run` never trace back.

Each corrupt variant of a small generated recording (`fuzz_mcap`) goes through the three
commands in-process. The contract, per command and variant:
- exit 0 or 2, never 1, never a traceback;
- exit 2: exactly one `error:` line on stderr, naming the file;
- exit 0: a warning names the file (salvage; for `convert` the output holds only
  messages of the clean file: nothing is invented), or, only where the damage can be in
  bytes no reader needs (`MAY_BE_HARMLESS`), the output equals the clean file's.
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from fuzz_mcap import corrupt_variants, without_crcs
from mcap.reader import make_reader
from test_readers_mcap import write_synthetic
from typer.testing import CliRunner, Result

from sonarmap.pipeline.cli import app

runner = CliRunner()
COMMANDS = ("topics", "convert", "run")
MAY_BE_HARMLESS = (
    "flip-header/",  # profile and library strings
    "flip-chunk-header/start_time",  # the summary's chunk index is what readers use
    "flip-chunk-header/end_time",
    "flip-chunk-header/records_len",  # zstd stops at the end of its frame
    "flip-index/message-index",  # checked against the chunk when a message is fetched
)


def _variants() -> dict[str, bytes]:
    # Built once at collection from a fixed recording: the ids name every case.
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "clean.mcap"
        write_synthetic(path, n_pings=12, chunk_size=16 * 1024)
        return corrupt_variants(path.read_bytes())


VARIANTS = _variants()


def invoke(args: list[str], caplog: pytest.LogCaptureFixture) -> tuple[Result, str]:
    """Run the CLI in-process; (result, warnings logged meanwhile)."""
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        res = runner.invoke(app, args)
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exc_info
    assert "Traceback" not in res.output
    return res, caplog.text


def check_refusal(res: Result, name: str) -> None:
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and name in errors[0], res.stderr
    other = [line for line in res.stderr.splitlines() if line.strip() and line not in errors]
    assert not other, res.stderr


def messages(path: Path) -> Counter[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return Counter(
            (c.topic, m.log_time, bytes(m.data))
            for _, c, m in make_reader(f).iter_messages(log_time_order=False)
            if c.topic != "/tf_static"
        )


def command_args(command: str, path: Path, tmp: Path) -> list[str]:
    if command == "topics":
        return ["topics", str(path), "--json"]
    if command == "convert":
        return ["convert", str(path), "-o", str(tmp / "out.mcap")]
    return ["run", str(path), "--until", "keyframes", "--store", str(tmp / "store"), "-q", "--json"]


def output_of(command: str, res: Result, tmp: Path) -> Any:
    """What a successful command produced, comparable across input files."""
    if command == "topics":
        doc = json.loads(res.stdout)
        doc.pop("path")
        return doc
    if command == "convert":
        return messages(tmp / "out.mcap")
    art = Path(json.loads(res.stdout)["stages"][0]["path"])
    return pq.read_table(art / "keyframes.parquet").to_pylist()


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The clean recording and what each command makes of it."""
    tmp = tmp_path_factory.mktemp("clean")
    path = tmp / "clean.mcap"
    write_synthetic(path, n_pings=12, chunk_size=16 * 1024)
    out: dict[str, Any] = {"path": path}
    for command in COMMANDS:
        res = runner.invoke(app, command_args(command, path, tmp))
        assert res.exit_code == 0, res.output
        out[command] = output_of(command, res, tmp)
    return out


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", sorted(VARIANTS))
def test_corrupt_mcap_is_refused_in_one_line_or_salvaged_with_a_warning(
    case: str,
    command: str,
    clean: dict[str, Any],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    path = tmp_path / "damaged.mcap"
    path.write_bytes(VARIANTS[case])
    res, warned = invoke(command_args(command, path, tmp_path), caplog)
    if res.exit_code != 0:
        check_refusal(res, str(path))
        assert not (tmp_path / "out.mcap").exists()  # convert leaves no partial output
        return
    got = output_of(command, res, tmp_path)
    if case.startswith(MAY_BE_HARMLESS) and got == clean[command]:
        return
    warnings = got["warnings"] if command == "topics" else [warned]
    assert any(str(path) in w for w in warnings), f"corruption passed silently: {res.output}"
    if command == "convert":
        assert not got - clean["convert"], "salvage invented messages"


@pytest.mark.parametrize("case", sorted(c for c in VARIANTS if c.startswith("flip-")))
def test_files_without_crcs_never_crash(
    case: str, clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # Without CRCs a flip that still decompresses cannot be seen; the rest must not crash.
    path = tmp_path / "nocrc.mcap"
    path.write_bytes(without_crcs(VARIANTS[case]))
    for command in COMMANDS:
        res, _ = invoke(command_args(command, path, tmp_path), caplog)
        if res.exit_code != 0:
            check_refusal(res, str(path))


def test_unchanged_file_without_crcs_reads_like_the_original(
    clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "nocrc.mcap"
    path.write_bytes(without_crcs(clean["path"].read_bytes()))
    for command in COMMANDS:
        res, _ = invoke(command_args(command, path, tmp_path), caplog)
        assert res.exit_code == 0 and output_of(command, res, tmp_path) == clean[command]


def test_crc_mismatch_names_file_and_chunk_offset(
    clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    case = next(c for c in sorted(VARIANTS) if c.startswith("flip-chunk-header/crc@"))
    path = tmp_path / "crc.mcap"
    path.write_bytes(VARIANTS[case])
    chunk_at = int(case.split("@")[1]) - 9 - 24
    for command in COMMANDS:
        res, _ = invoke(command_args(command, path, tmp_path), caplog)
        check_refusal(res, str(path))
        assert f"chunk at byte offset {chunk_at}: CRC mismatch" in res.stderr


@pytest.mark.parametrize("suffix", [".bag", ".db3", ".txt", ""])
def test_extension_does_not_decide_the_format(
    suffix: str, clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    renamed = tmp_path / f"recording{suffix}"
    renamed.write_bytes(clean["path"].read_bytes())
    res, _ = invoke(["topics", str(renamed), "--json"], caplog)
    assert res.exit_code == 0 and output_of("topics", res, tmp_path) == clean["topics"]
    text = tmp_path / f"notes{suffix or '.none'}.mcap"
    text.write_text("not a recording\n")
    for command in COMMANDS:
        check_refusal(invoke(command_args(command, text, tmp_path), caplog)[0], str(text))


def test_directories_and_missing_paths_exit_2(
    clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    plain = tmp_path / "plain_dir"
    plain.mkdir()
    missing = tmp_path / "gone.mcap"
    for target in (plain, missing):
        for command in COMMANDS:
            check_refusal(invoke(command_args(command, target, tmp_path), caplog)[0], str(target))
    store = str(tmp_path / "store")
    forced = ["run", str(missing), "--force", "keyframes", "--store", store, "-q"]
    check_refusal(invoke(forced, caplog)[0], str(missing))


BAD_METADATA = {
    "syntax": "rosbag2_bagfile_information:\n  relative_file_paths: [a.mcap\n",
    "tab": "rosbag2_bagfile_information:\n\tversion: 5\n",
    "not-a-mapping": "- just\n- a list\n",
    "binary": b"\xff\xfe\x00rosbag",
}


@pytest.mark.parametrize("kind", sorted(BAD_METADATA))
def test_bag_metadata_faults_are_one_line(
    kind: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    text = BAD_METADATA[kind]
    meta = bag / "metadata.yaml"
    meta.write_bytes(text if isinstance(text, bytes) else text.encode())
    for command in COMMANDS:
        res, _ = invoke(command_args(command, bag, tmp_path), caplog)
        check_refusal(res, str(meta))
        if kind == "syntax":
            assert "line 3:1" in res.stderr and "line 2:24" in res.stderr


def test_bag_with_a_missing_data_file_exits_2_also_under_force(
    clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.mcap").write_bytes(clean["path"].read_bytes())
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
        "  relative_file_paths: [bag_0.mcap, bag_1.mcap]\n"
    )
    store = str(tmp_path / "store")
    for extra in ([], ["--force", "keyframes"]):
        res, _ = invoke(["run", str(bag), "--until", "keyframes", "--store", store, *extra], caplog)
        check_refusal(res, str(bag))


@pytest.mark.parametrize(
    "case", sorted(c for c in VARIANTS if c.startswith(("flip-index/summary", "flip-index/footer")))
)
def test_damaged_summary_is_read_sequentially_with_every_message(
    case: str, clean: dict[str, Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "summary.mcap"
    path.write_bytes(VARIANTS[case])
    res, warned = invoke(command_args("convert", path, tmp_path), caplog)
    assert res.exit_code == 0 and output_of("convert", res, tmp_path) == clean["convert"]
    assert f"{path}: the " in warned and "read sequentially instead" in warned, warned
