"""User paths at the CLI boundary: an OSError naming a file is one `error:` line and exit 2,
every error line is escaped and bounded, symlinked recordings run, `status` plans every
stage (the model included), and every `--json` output is strict JSON."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.commands._errors import (
    MAX_LINE_CHARS,
    display_path,
    one_line,
    os_error_line,
    writes_under,
)
from sonarmap.pipeline.engine.errors import OutputError, StageFailed

ROOT = Path(__file__).resolve().parent.parent


def _strict(text: str) -> object:
    def refuse(name: str) -> object:
        raise ValueError(f"not strict JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def _error_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("error:")]


# --- the pieces -------------------------------------------------------------------------


def test_one_line_escapes_controls_separators_and_undecodable_bytes() -> None:
    text = one_line("a\nb\rc\x1b[31md\u2028e" + os.fsdecode(b"\xff"))
    assert "\n" not in text and "\r" not in text and "\x1b" not in text
    # The undecodable byte of a file name shows as the byte, as `ls -b` shows it.
    assert text == "a\\nb\\rc\\e[31md\\u2028e\\xff"
    text.encode("utf-8")  # printable on any UTF-8 stderr
    assert one_line("\udc7f") == "\\udc7f"  # a lone surrogate that is no such byte


def test_long_paths_are_shortened_in_the_middle_and_lines_bounded() -> None:
    path = "/data/" + "x" * 1000 + "/dive.mcap"
    shown = display_path(path)
    assert shown.startswith("/data/x") and shown.endswith("/dive.mcap") and "…" in shown
    assert len(shown) < 200
    assert len(one_line("y" * 10_000)) == MAX_LINE_CHARS


def test_only_os_errors_naming_a_file_become_a_path_line() -> None:
    named = OSError(errno.ENAMETOOLONG, "File name too long", "/a/b\nc")
    assert os_error_line(named) == "/a/b\\nc: File name too long"
    assert os_error_line(OSError(errno.EIO, "Input/output error")) is None


def test_a_full_disk_while_writing_is_blamed_on_the_named_output(tmp_path: Path) -> None:
    full = pytest.raises(OutputError, match=f"^{tmp_path}: No space left on device")
    with full, writes_under(tmp_path):
        raise OSError(errno.ENOSPC, "No space left on device")
    # A stage whose write failed on a full disk is the disk's fault, not a bug either.
    with pytest.raises(OutputError, match="Read-only file system"), writes_under(tmp_path):
        try:
            raise OSError(errno.EROFS, "Read-only file system")
        except OSError as err:
            raise StageFailed("stage fuse failed: OSError") from err
    with pytest.raises(OSError, match="Input/output"), writes_under(tmp_path):
        raise OSError(errno.EIO, "Input/output error")  # no file, not a disk: a bug


# --- through the CLI (toy stages) -------------------------------------------------------


def test_path_component_over_255_chars_is_exit_2(toy_cli: Path, tmp_path: Path) -> None:
    long = tmp_path / ("n" * 300 + ".bin")
    res = CliRunner().invoke(app, ["run", str(long), "--store", str(tmp_path / "s")])
    assert res.exit_code == 2, res.output
    [line] = _error_lines(res.stderr)
    assert line.endswith(".bin: File name too long") and "…" in line
    assert "Traceback" not in res.stderr


def test_store_under_a_long_component_is_exit_2(toy_cli: Path, tmp_path: Path) -> None:
    store = tmp_path / ("s" * 300)
    res = CliRunner().invoke(app, ["run", str(toy_cli), "--store", str(store)])
    assert res.exit_code == 2, res.output
    assert "File name too long" in _error_lines(res.stderr)[0]


@pytest.mark.parametrize("name", ["new\nline.bin", "carriage\rreturn.bin", "esc\x1b[2J.bin"])
def test_control_characters_in_a_path_never_split_the_error(
    toy_cli: Path, tmp_path: Path, name: str
) -> None:
    res = CliRunner().invoke(app, ["run", str(tmp_path / name), "--store", str(tmp_path / "s")])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines == _error_lines(res.stderr)
    assert "\r" not in res.stderr and "\x1b" not in res.stderr


def test_store_inside_a_file_named_with_a_newline_is_one_line(
    toy_cli: Path, tmp_path: Path
) -> None:
    blocker = tmp_path / "not\na folder"
    blocker.write_text("x")
    res = CliRunner().invoke(app, ["run", str(toy_cli), "--store", str(blocker / "store")])
    assert res.exit_code == 2, res.output
    [line] = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert line.startswith(f"error: {tmp_path}/not\\na folder")


def test_read_only_store_is_exit_2(toy_cli: Path, tmp_path: Path) -> None:
    target = Path("/sys/sonarmap-test-store")
    try:
        target.mkdir()
    except OSError:
        pass
    else:
        target.rmdir()
        pytest.skip("/sys is writable here")
    res = CliRunner().invoke(app, ["run", str(toy_cli), "--store", str(target)])
    assert res.exit_code == 2, res.output
    assert _error_lines(res.stderr)[0].startswith(f"error: {target}:")


def test_os_error_without_a_file_stays_a_bug(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sonarmap.pipeline.api

    def broken(*_a: object, **_k: object) -> None:
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(sonarmap.pipeline.api, "run_dataset", broken)
    res = CliRunner().invoke(app, ["run", str(toy_cli), "--store", str(tmp_path / "s")])
    # A bug: exit 1, one line from the CLI's last-resort handler (issue 52), no traceback.
    assert res.exit_code == 1
    assert _error_lines(res.stderr) == [
        "error: internal error: OSError: [Errno 5] Input/output error"
    ]


# --- a real run on the tiny scene, with the shipped model ------------------------------


@pytest.fixture(scope="module")
def real_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 15 s tiny-scene mission mapped once by `sonarmap run` with its output in a log
    file (not a terminal), through a symlink from another directory; tests copy
    the store before damaging it."""
    from sonarmap.pipeline.training.datasets import Simulation, ensure_simulations, scene_path

    work = tmp_path_factory.mktemp("real")
    recording = work / "recordings" / "tiny.mcap"
    ensure_simulations([Simulation(scene_path("tiny"), 2, recording, duration_s=15.0)], 1)
    link = work / "elsewhere" / "linked.mcap"
    link.parent.mkdir()
    link.symlink_to(recording)
    log = work / "log.txt"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("COLUMNS", None)
    with log.open("w") as out:
        res = subprocess.run(
            [
                sys.executable,
                "-m",
                "sonarmap.pipeline",
                "run",
                str(link),
                "--store",
                str(work / "store"),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            env=env,
            timeout=600,
        )
    assert res.returncode == 0, log.read_text()[-3000:]
    return {"recording": recording, "link": link, "store": work / "store", "log": log}


def test_symlinked_recording_runs_and_shares_the_target_fingerprint(
    real_run: dict[str, Path],
) -> None:
    runner = CliRunner()
    store = str(real_run["store"])
    direct = runner.invoke(app, ["status", str(real_run["recording"]), "--store", store, "--json"])
    linked = runner.invoke(app, ["status", str(real_run["link"]), "--store", store, "--json"])
    assert direct.exit_code == 0 and linked.exit_code == 0, direct.output + linked.output
    assert _strict(direct.stdout)["stages"] == _strict(linked.stdout)["stages"]


def test_a_recording_under_another_name_gives_the_same_bytes(
    real_run: dict[str, Path], tmp_path: Path
) -> None:
    """Keys hold a recording's content, not its name: its keyframes (sensors.json with
    them) are the same bytes whatever the file is called (campaign 6 #12)."""
    renamed = tmp_path / "another name é.mcap"
    renamed.symlink_to(real_run["recording"])
    store = tmp_path / "store"
    res = CliRunner().invoke(
        app, ["run", str(renamed), "--store", str(store), "--until", "keyframes", "--json"]
    )
    assert res.exit_code == 0, res.output
    [ours] = (store / "keyframes").glob("*/sensors.json")
    theirs = real_run["store"] / "keyframes" / ours.parent.name / "sensors.json"
    assert ours.read_bytes() == theirs.read_bytes()
    assert b"linked" not in ours.read_bytes() and b"tiny" not in ours.read_bytes()


def test_status_plans_every_stage_with_the_model(real_run: dict[str, Path]) -> None:
    res = CliRunner().invoke(
        app, ["status", str(real_run["link"]), "--store", str(real_run["store"]), "--json"]
    )
    assert res.exit_code == 0, res.output
    rows = _strict(res.stdout)["stages"]
    assert [r["stage"] for r in rows] == [
        "train", "keyframes", "features", "fuse", "classify",
        "slam", "infer", "submaps", "voxelize", "evaluate", "figures", "map_figures",
    ]  # fmt: skip
    assert {r["status"] for r in rows} == {"hit"}, rows
    # Changing a stage past the model's readers misses from there on, with the model kept.
    res = CliRunner().invoke(
        app,
        [
            "status", str(real_run["link"]), "--store", str(real_run["store"]), "--json",
            "--set", "classify.mc_passes=3",
        ],
    )  # fmt: skip
    rows = {r["stage"]: r["status"] for r in _strict(res.stdout)["stages"]}
    assert rows["train"] == "hit" and rows["fuse"] == "hit" and rows["classify"] == "miss"


def test_the_run_summary_in_a_log_file_is_never_cut(real_run: dict[str, Path]) -> None:
    log = real_run["log"].read_text()
    for word in ("SE(2)-aligned", "completeness", "semantic/standard"):
        assert word in log
    assert "…" not in log
    assert str(real_run["store"] / "evaluate") in log  # artifact paths whole


def test_every_json_output_is_strict(real_run: dict[str, Path]) -> None:
    store = str(real_run["store"])
    runner = CliRunner()
    for args in (
        ["run", str(real_run["link"]), "--store", store, "--json", "-q"],
        ["status", str(real_run["link"]), "--store", store, "--json"],
        ["ls", "--store", store, "--json"],
        *(["show", stage, "--store", store, "--json"] for stage in ("fuse", "evaluate", "train")),
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 0, (args, res.output)
        _strict(res.stdout)


def test_json_with_non_finite_values_is_strict(tmp_path: Path) -> None:
    """A manifest holding NaN and infinities (as fuse's did) prints them as null."""
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    store = ArtifactStore(tmp_path / "s")

    def build(tmp: Path) -> dict[str, object]:
        (tmp / "x.json").write_text("{}")
        return {"outputs": {"fused": {"rows": 0, "median_cost": float("nan")}}}

    store.commit("fuse", "ab" * 32, build, {"config": {"limit": float("inf")}})
    runner = CliRunner()
    show = runner.invoke(app, ["show", "fuse", "--store", str(store.root), "--json"])
    assert show.exit_code == 0, show.output
    doc = _strict(show.stdout)
    assert doc["manifest"]["outputs"]["fused"]["median_cost"] is None
    assert doc["manifest"]["config"]["limit"] is None
    res = runner.invoke(app, ["ls", "--store", str(store.root), "--json"])
    assert res.exit_code == 0, res.output
    _strict(res.stdout)


def test_status_without_a_plannable_model_lists_every_stage(real_run: dict[str, Path]) -> None:
    """With no shipped lock the model's key needs its training sets simulated: `status`
    still lists every stage, planning those that read no stage reading the model."""
    res = CliRunner().invoke(
        app,
        [
            "status", str(real_run["link"]), "--store", str(real_run["store"]), "--json",
            "--set", "training.shipped_models=null",
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    rows = {r["stage"]: r for r in _strict(res.stdout)["stages"]}
    assert rows["train"]["status"] == "miss" and rows["keyframes"]["status"] == "hit"
    assert rows["evaluate"]["status"] == "miss" and "model" in rows["evaluate"]["reason"]
    # slam reads no stage that reads the model: planned, and a hit as `run` would find it.
    assert rows["slam"]["status"] == "hit" and rows["slam"]["key"], rows["slam"]
    assert list(rows).index("slam") == list(rows).index("classify") + 1  # graph order


def test_no_figures_leaves_the_figure_stages_out_and_the_map_needs_no_matplotlib(
    real_run: dict[str, Path],
) -> None:
    recording, store = str(real_run["recording"]), str(real_run["store"])
    res = CliRunner().invoke(app, ["status", recording, "--store", store, "--json", "--no-figures"])
    assert res.exit_code == 0, res.output
    planned = [r["stage"] for r in _strict(res.stdout)["stages"]]
    assert planned[-1] == "evaluate" and not {"figures", "map_figures"} & set(planned)
    # The stages that drew figures before, recomputed where matplotlib cannot be imported.
    code = "import sys; sys.modules['matplotlib'] = None; from pipeline.cli import main; main()"
    recomputed = ("classify", "slam", "voxelize", "evaluate")
    forced = [arg for stage in recomputed for arg in ("--force", stage)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [recording, "--store", store, "--json", "--workers", "1", "--no-figures", *forced]
    done = subprocess.run(
        [sys.executable, "-c", code, "run", *args],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    status = {s["stage"]: s["status"] for s in _strict(done.stdout)["stages"]}
    assert list(status)[-1] == "evaluate" and status["evaluate"] == "computed"
    # With figures (the default), the same map keys: only the figures' artifacts are read.
    res = CliRunner().invoke(app, ["run", recording, "--store", store, "--json"])
    assert res.exit_code == 0, res.output
    stages = {s["stage"]: s for s in _strict(res.stdout)["stages"]}
    assert {s["status"] for s in stages.values()} == {"hit"}
    pngs = {p.name for s in ("figures", "map_figures") for p in Path(stages[s]["path"]).iterdir()}
    assert {"overlay.png", "trajectory.png", "errors.png", "map_topdown.png"} <= pngs
    assert not any(p.suffix == ".png" for p in Path(stages["evaluate"]["path"]).iterdir())


# --- campaign 9 and 11: status and keys on the real run --------------------------------


def _status(recording: Path, store: Path, *extra: str) -> dict[str, dict[str, str]]:
    res = CliRunner().invoke(
        app, ["status", str(recording), "--store", str(store), "--json", *extra]
    )
    assert res.exit_code == 0, res.output
    return {r["stage"]: r for r in json.loads(res.stdout)["stages"]}


def test_status_calls_a_hit_with_a_missing_file_damaged(
    real_run: dict[str, Path], tmp_path: Path
) -> None:
    """It said "hit": the run that then read the artifact stopped with exit 2."""
    store = tmp_path / "store"
    shutil.copytree(real_run["store"], store)
    [fused] = (store / "fuse").glob("*/fused.parquet")
    fused.unlink()
    rows = _status(real_run["recording"], store)
    assert rows["fuse"]["status"] == "damaged", rows["fuse"]
    assert "'fused.parquet' is missing" in rows["fuse"]["reason"]
    assert "gc --broken" in rows["fuse"]["reason"]
    assert rows["keyframes"]["status"] == "hit"


def test_a_setting_read_by_another_stage_is_named_in_its_miss_reason(
    real_run: dict[str, Path],
) -> None:
    """figures reads the slam section: its reason printed both whole sections (3885 chars)."""
    rows = _status(real_run["recording"], real_run["store"], "--set", "slam.heading_sigma_deg=0.4")
    reason = rows["figures"]["reason"]
    assert reason.startswith("config changed: slam.heading_sigma_deg ") and "-> 0.4" in reason
    assert len(reason) < 120, reason
