"""CLI contract: exit codes, one JSON document with --json, --help everywhere."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app

runner = CliRunner()


def test_run_json_then_status_reports_hits(toy_cli: Path, tmp_path: Path) -> None:
    store = str(tmp_path / "store")
    first = runner.invoke(app, ["run", str(toy_cli), "--store", store, "--json", "-q"])
    assert first.exit_code == 0, first.output
    doc = json.loads(first.stdout)
    assert [s["status"] for s in doc["stages"]] == ["computed"] * 4
    assert all(Path(s["path"]).is_dir() for s in doc["stages"])
    assert set(doc) >= {"dataset", "store", "stages", "summary"}
    status = runner.invoke(
        app, ["status", str(toy_cli), "--store", store, "--json", "--set", "count.bins=9"]
    )
    assert status.exit_code == 0, status.output
    rows = {r["stage"]: r for r in json.loads(status.stdout)["stages"]}
    assert rows["source"]["status"] == "hit"
    assert rows["count"]["status"] == "miss"
    assert rows["count"]["reason"] == "config changed: count.bins 4 -> 9"


def test_show_ls_gc_json(toy_cli: Path, tmp_path: Path) -> None:
    store = str(tmp_path / "store")
    assert runner.invoke(app, ["run", str(toy_cli), "--store", store, "-q"]).exit_code == 0
    shown = runner.invoke(app, ["show", "double", "--store", store, "--verify", "--json"])
    assert shown.exit_code == 0, shown.output
    assert json.loads(shown.stdout)["manifest"]["stage"] == "double"
    listed = json.loads(runner.invoke(app, ["ls", "--store", store, "--json"]).stdout)
    assert len(listed["artifacts"]) == 4
    collected = json.loads(runner.invoke(app, ["gc", "--store", store, "--json"]).stdout)
    assert collected["removed"] == [] and collected["kept"] == 4


def test_bad_input_exit_2_one_line(toy_cli: Path, tmp_path: Path) -> None:
    store = str(tmp_path / "store")
    missing = runner.invoke(app, ["run", str(tmp_path / "nope.mcap"), "--store", store])
    assert missing.exit_code == 2
    assert missing.stderr.strip().count("\n") == 0 and "nope.mcap" in missing.stderr
    bad_key = runner.invoke(app, ["run", str(toy_cli), "--store", store, "--set", "double.fctor=1"])
    assert bad_key.exit_code == 2 and "double.factor" in bad_key.stderr
    assert "Traceback" not in bad_key.output
    unknown = runner.invoke(app, ["show", "nothing", "--store", store])
    assert unknown.exit_code == 2


def test_stage_failure_exit_1_names_stage(toy_cli: Path, tmp_path: Path) -> None:
    store = str(tmp_path / "store")
    res = runner.invoke(app, ["run", str(toy_cli), "--store", store, "--set", "summary.fail=true"])
    assert res.exit_code == 1
    assert "stage summary failed" in res.stderr


def test_config_dump_and_check(toy_cli: Path, tmp_path: Path) -> None:
    dumped = runner.invoke(app, ["config", "dump", "--json"])
    assert dumped.exit_code == 0
    assert json.loads(dumped.stdout)["double"]["factor"] == 2
    good = tmp_path / "good.yaml"
    good.write_text("double:\n  factor: 5\n")
    assert runner.invoke(app, ["config", "check", str(good)]).exit_code == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("doubel:\n  factor: 5\n")
    res = runner.invoke(app, ["config", "check", str(bad)])
    assert res.exit_code == 2 and "'double'" in res.stderr


def _commands() -> list[list[str]]:
    import typer.main

    group = typer.main.get_command(app)
    names: list[list[str]] = [[]]
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        names.append([name])
        for sub in getattr(cmd, "commands", {}):
            names.append([name, sub])
    return names


@pytest.mark.parametrize("cmd", _commands(), ids=lambda c: " ".join(c) or "root")
def test_every_command_has_help(cmd: list[str]) -> None:
    res = runner.invoke(app, [*cmd, "--help"])
    assert res.exit_code == 0, res.output
    assert "Usage" in res.output


def test_version_and_fast_help_subprocess() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.startswith("sonarmap ")
    # --help must not import the heavy libraries.
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from pipeline.cli import app; "
            "print(sorted(m for m in ('torch','open3d','gtsam','pyarrow','mcap') if m in sys.modules))",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert probe.stdout.strip() == "[]"


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["follow", "x.mcap", "--poll-s", "nan"], "--poll-s"),
        (["run", "x.mcap", "--no-such-option"], "No such option: --no-such-option"),
        (["sweep", "x.mcap", "-j", "abc"], "--jobs"),
        (["run"], "Missing argument"),
        (["--no-such-option", "ls"], "No such option: --no-such-option"),
    ],
)
def test_a_bad_option_of_a_command_is_one_error_line(args: list[str], words: str) -> None:
    res = CliRunner().invoke(app, args, env={"COLUMNS": "40"})
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], lines
    command = "" if args[0].startswith("-") else f" {args[0]}"
    assert lines[0].endswith(f"(sonarmap{command} --help)")


def test_a_failed_json_command_still_prints_one_document(tmp_path: Path) -> None:
    """A program reading `--json` stdout learns why there is no result: the same line as
    stderr's `error:`, and the exit code."""
    missing = tmp_path / "nope.mcap"
    res = runner.invoke(app, ["run", str(missing), "--store", str(tmp_path / "s"), "--json"])
    assert res.exit_code == 2
    doc = json.loads(res.stdout)
    assert doc == {"error": f"{missing}: no such file or directory", "exit_code": 2}
    assert res.stderr.strip() == f"error: {doc['error']}"
    plain = runner.invoke(app, ["run", str(missing), "--store", str(tmp_path / "s")])
    assert plain.exit_code == 2 and plain.stdout == ""
    # Refused before any stage started: no empty progress display, no blank line.
    assert plain.stderr == f"error: {doc['error']}\n"


def test_a_reader_that_closes_stdout_early_is_no_internal_error(tmp_path: Path) -> None:
    """`sonarmap ... | head`: the pipe is closed before sonarmap writes (deterministic)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        res = subprocess.run(
            [sys.executable, "-m", "sonarmap.pipeline", "topics", "--help"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write_end)
    assert res.returncode == 1
    assert "internal error" not in res.stderr and "Traceback" not in res.stderr, res.stderr



@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("training:\n  sets:\n    - {scene: TMP/text.yaml, seed: 1, goals: 2}\n", "training.sets[0].scene"),
        ("training:\n  recorded: [/nonexistent/x.mcap]\n", "training.recorded[0]: /nonexistent"),
        ("classify:\n  model: /etc\n", "classify.model: /etc: not a model folder"),
        ("keyframes:\n  message_definitions: ['TMP/text.yaml']\n", "keyframes.message_definitions"),
    ],
    ids=["scene", "recorded", "model", "definitions"],
)
def test_config_check_reads_what_the_config_names_as_a_run_would(
    tmp_path: Path, text: str, words: str
) -> None:
    """`config check` said ok to configs `run` then refused (a scene that is no scene, a
    recording that is not there, a folder that holds no model, a file that is no .msg)."""
    (tmp_path / "text.yaml").write_text("just a sentence\n")
    path = tmp_path / "c.yaml"
    path.write_text(text.replace("TMP", str(tmp_path)))
    res = runner.invoke(app, ["config", "check", str(path)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and words in lines[0], lines


def test_show_verify_refuses_an_artifact_without_a_file_its_stage_always_writes(
    tmp_path: Path,
) -> None:
    """Every file the manifest listed matched, so `--verify` said verified, and the next
    stage failed on the file the manifest did not list."""
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    def build(tmp: Path) -> dict:
        (tmp / "notes.txt").write_text("not the fused points\n")
        return {}

    from sonarmap.pipeline.engine.hashing import recipe_key

    recipe = {"stage": "fuse", "version": 0}
    ArtifactStore(tmp_path / "s").commit("fuse", recipe_key(recipe), build, {"recipe": recipe})
    res = runner.invoke(app, ["show", "fuse", "--verify", "--store", str(tmp_path / "s")])
    assert res.exit_code == 2, res.output
    assert "lists no 'fused.parquet', which every fuse artifact holds" in res.stderr
