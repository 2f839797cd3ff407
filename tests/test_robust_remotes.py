"""Remotes that time out and say why (issue 52, root 4): connect and read timeouts on
every remote, listing caps, credentials scrubbed from every message (a last-resort
handler at the CLI), a missing bucket refused unless --create, and errors that name the
remote, the operation and the cause. Servers are started here on 127.0.0.1."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_share_remotes import _free_port, alice, s3_env  # noqa: F401 - fixtures
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import StoreError
from sonarmap.pipeline.engine.share import remote_index
from sonarmap.pipeline.engine.share.push_pull import list_remote
from tests.fixtures.hostile_http import misbehaving_server

ROOT = Path(__file__).resolve().parents[1]


def _cli(env: dict[str, str], *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", *args],
        capture_output=True,
        text=True,
        env={**env, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore"},
        cwd=ROOT,
        timeout=timeout,
    )


def _one_error(res: subprocess.CompletedProcess[str], code: int = 2) -> str:
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert res.returncode == code and len(errors) == 1, res.stderr[-3000:]
    assert "Traceback" not in res.stderr and len(errors[0]) <= 400
    return errors[0]


@pytest.fixture
def silent_server() -> Iterator[int]:
    """Accepts connections and never answers."""
    with misbehaving_server("silent") as port:
        yield port


def test_an_http_remote_that_never_answers_times_out(silent_server: int, tmp_path: Path) -> None:
    env = {**os.environ, "SONARMAP_REMOTE_TIMEOUT_S": "2"}
    t0 = time.monotonic()
    res = _cli(env, "pull", f"http://127.0.0.1:{silent_server}/lab", "--store", str(tmp_path / "s"))
    line = _one_error(res)
    assert time.monotonic() - t0 < 20
    assert f"remote http://127.0.0.1:{silent_server}/lab: pull: timed out" in line
    from sonarmap.pipeline.engine.share.remotes import DEFAULT_TIMEOUT_S

    assert DEFAULT_TIMEOUT_S <= 20


def test_an_http_redirect_loop_is_named(tmp_path: Path) -> None:
    with misbehaving_server("redirect_loop") as port:
        url = f"http://127.0.0.1:{port}/lab"
        res = _cli(dict(os.environ), "pull", url, "--store", str(tmp_path / "s"))
    assert "redirect loop" in _one_error(res)


def _offline_s3(tmp_path: Path) -> dict[str, str]:
    return {
        **os.environ,
        "AWS_ACCESS_KEY_ID": "x",
        "AWS_SECRET_ACCESS_KEY": "y",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{_free_port()}",  # nothing listens
        "AWS_CONFIG_FILE": str(tmp_path / "none"),
        "AWS_SHARED_CREDENTIALS_FILE": str(tmp_path / "none"),
        "SONARMAP_REMOTE_TIMEOUT_S": "2",
    }


def test_a_secret_in_an_invalid_bucket_url_is_never_printed(
    tmp_path: Path,
    alice: Path,  # noqa: F811
) -> None:
    pytest.importorskip("s3fs")
    secret = "sEcReTkEy0123456789"
    url = f"s3://AKIDKEY:{secret}@Bad_Bucket!!/x"
    res = _cli(_offline_s3(tmp_path), "push", url, "--store", str(alice))
    _one_error(res, res.returncode)
    assert res.returncode in (1, 2)
    assert secret not in res.stderr + res.stdout and "AKIDKEY" not in res.stderr


def test_a_connection_refused_mid_push_names_remote_operation_cause(
    tmp_path: Path,
    alice: Path,  # noqa: F811
) -> None:
    pytest.importorskip("s3fs")
    res = _cli(_offline_s3(tmp_path), "push", "s3://lab/x", "--store", str(alice))
    line = _one_error(res)
    assert "remote s3://lab/x: push: connection dropped" in line, line
    assert "Task exception was never retrieved" not in res.stderr


def test_push_to_a_bucket_that_does_not_exist_needs_create(
    tmp_path: Path,
    alice: Path,  # noqa: F811
    s3_env: dict[str, str],  # noqa: F811
) -> None:
    res = _cli(s3_env, "push", "s3://newbucket/shared", "--store", str(alice))
    line = _one_error(res)
    assert "bucket 'newbucket' does not exist (pass --create" in line
    res = _cli(s3_env, "push", "s3://newbucket/shared", "--store", str(alice), "--create")
    assert res.returncode == 0, res.stderr[-2000:]


def test_wrong_credentials_are_named_as_such() -> None:
    from sonarmap.pipeline.engine.share.remotes import remote_failure

    err = remote_failure(PermissionError("Forbidden"), "s3://K:S@lab/x", "push")
    assert (
        str(err) == "remote s3://lab/x: push: access denied (check the credentials) "
        "(PermissionError: Forbidden)"
    )


def test_a_listing_over_the_cap_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    remote = tmp_path / "remote"
    for k in range(8):
        (remote / f"stage{k}").mkdir(parents=True)
    monkeypatch.setattr(remote_index, "MAX_LISTING", 5)
    with pytest.raises(StoreError, match="lists 8 entries, over the limit of 5"):
        list_remote(str(remote))


def test_a_ten_thousand_character_set_value_stays_one_line_of_400(tmp_path: Path) -> None:
    res = CliRunner().invoke(
        app,
        [
            "convert",
            str(tmp_path / "x.mcap"),
            "-o",
            str(tmp_path / "o.mcap"),
            "--set",
            "x" * 10_000,
        ],
    )
    [line] = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert res.exit_code == 2 and len(line) <= 400


def test_the_last_resort_handler_prints_one_line_without_credentials(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import sonarmap.pipeline.engine.share.push_pull as share

    def broken(*_a: object, **_k: object) -> None:
        raise RuntimeError("could not reach https://AKID:SECRET@bucket.example/x")

    monkeypatch.setattr(share, "list_remote", broken)
    monkeypatch.setattr(share, "pull", broken)
    res = CliRunner().invoke(app, ["pull", "https://AKID:SECRET@bucket.example/x"])
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 1 and len(lines) == 1, res.output
    assert lines[0].startswith("error: internal error: RuntimeError: could not reach")
    assert "SECRET" not in res.output and "AKID" not in res.output


def test_orphan_task_noise_after_a_failed_transfer_is_not_printed() -> None:
    from sonarmap.pipeline.cli import _OrphanTasks

    noise = logging.LogRecord("asyncio", logging.ERROR, "", 0, "Task exception was never retrieved", (), None)  # fmt: skip
    real = logging.LogRecord("sonarmap", logging.ERROR, "", 0, "never retrieved", (), None)
    assert not _OrphanTasks().filter(noise) and _OrphanTasks().filter(real)


def test_wrong_s3_credentials_say_access_denied(
    tmp_path: Path,
    alice: Path,  # noqa: F811
) -> None:
    pytest.importorskip("moto.server", reason="moto[server] is not installed")
    pytest.importorskip("s3fs")
    from test_share_remotes import _wait_port

    port = _free_port()
    # moto checks signatures once INITIAL_NO_AUTH_ACTION_COUNT actions are used up: 0.
    code = "from moto.server import main; main()"
    server = subprocess.Popen(
        [sys.executable, "-c", code, "-H", "127.0.0.1", "-p", str(port)],
        env={**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": "0"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_port(port, server)
        env = {**_offline_s3(tmp_path), "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{port}"}
        env["AWS_SECRET_ACCESS_KEY"] = "wrongSECRETvalue"
        for op, store in (("push", alice), ("pull", tmp_path / "bob")):
            res = _cli(env, op, "s3://lab/x", "--store", str(store))
            line = _one_error(res)
            assert f"remote s3://lab/x: {op}: access denied (check the credentials)" in line
            assert "wrongSECRETvalue" not in res.stderr
    finally:
        server.terminate()
        server.wait(10)


def test_push_to_a_folder_that_does_not_exist_needs_create(
    tmp_path: Path,
    alice: Path,  # noqa: F811
) -> None:
    remote = tmp_path / "shraed" / "sonar"  # a typo: nothing is grown there
    res = CliRunner().invoke(app, ["push", str(remote), "--store", str(alice)])
    [line] = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert res.exit_code == 2 and not remote.parent.exists(), res.output
    assert f"push: folder '{remote}' does not exist (pass --create to create it)" in line
    (tmp_path / "file").write_text("x")
    res = CliRunner().invoke(app, ["push", str(tmp_path / "file"), "--store", str(alice)])
    assert res.exit_code == 2 and "is not a folder" in res.output, res.output
    res = CliRunner().invoke(app, ["push", str(remote), "--create", "--store", str(alice)])
    assert res.exit_code == 0, res.output
    assert len(list(remote.glob("*/*/manifest.json"))) == len(list(alice.glob("*/*/manifest.json")))
