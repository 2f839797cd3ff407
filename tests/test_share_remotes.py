"""push/pull through the remotes labs use, each against a real server the test starts:
S3 (moto's standalone server), SFTP (OpenSSH's sshd, throwaway keys), HTTP (http.server).

Credentials come from the standard places (AWS environment, ~/.ssh/config) and must never
appear in any output, artifact, manifest or remote file.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_engine_cache import run_toy

from sonarmap.pipeline.engine.share.push_pull import list_remote, pull, push
from sonarmap.pipeline.engine.share.transfer import TransferStats
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

ROOT = Path(__file__).resolve().parents[1]
SSHD = shutil.which("sshd") or "/usr/sbin/sshd"
AWS_ID = "AKIDsonarmapTESTID0001"
AWS_SECRET = "s3cretSONARMAPtestKEYdoNotLeak0123456789"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, proc: subprocess.Popen[bytes] | None = None) -> None:
    for _ in range(200):
        if proc is not None and proc.poll() is not None:
            pytest.fail(f"server exited with {proc.returncode}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    pytest.fail(f"nothing listens on 127.0.0.1:{port}")


def _cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    """The real CLI in a subprocess, so every byte it prints (logs included) is captured."""
    return subprocess.run(
        [sys.executable, "-m", "sonarmap.pipeline", "-v", *args],
        capture_output=True,
        text=True,
        env={**env, "PYTHONPATH": str(ROOT)},
        cwd=ROOT,
        timeout=120,
    )


@pytest.fixture(scope="module")
def alice(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("alice")
    data = root / "raw.bin"
    data.write_bytes(bytes(range(256)) * 64)
    run_toy(data, root / "store")
    return root / "store"


def _assert_round_trip(
    alice: Path, remote: str, tmp_path: Path, env: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> str:
    """Push by the CLI (its whole output is returned), push again and pull in-process with
    the same environment: nothing is re-sent, everything arrives verified."""
    res = _cli(
        env, "push", remote, "--create", "--store", str(alice), "--model-cache", str(tmp_path / "c")
    )
    assert res.returncode == 0, res.stderr
    for name, value in env.items():
        if os.environ.get(name) != value:
            monkeypatch.setenv(name, value)
    stats = TransferStats()
    push(ArtifactStore(alice), remote, stats=stats)
    assert stats.sent == 0 and stats.skipped == 0  # every manifest is there: nothing to do
    expected = sorted(f"{r.stage}/{r.key}" for r in ArtifactStore(alice).iter_artifacts())
    assert sorted(list_remote(remote)) == expected
    bob = ArtifactStore(tmp_path / "bob")
    pull(bob, remote)
    assert sorted(f"{r.stage}/{r.key}" for r in bob.iter_artifacts()) == expected
    for ref in bob.iter_artifacts():
        bob.verify(ref)
    return res.stdout + res.stderr


def _no_secret_anywhere(text: str, roots: list[Path], secrets: list[str]) -> None:
    for secret in secrets:
        assert secret not in text
        for root in roots:
            for f in root.rglob("*"):
                if f.is_file():
                    assert secret.encode() not in f.read_bytes(), f


# -- S3 ----------------------------------------------------------------------------------


@pytest.fixture
def s3_env(tmp_path: Path) -> Iterator[dict[str, str]]:
    server_mod = pytest.importorskip("moto.server", reason="moto[server] is not installed")
    pytest.importorskip("s3fs", reason="s3fs is not installed")
    port = _free_port()
    server = server_mod.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    env = {
        **os.environ,
        "AWS_ACCESS_KEY_ID": AWS_ID,
        "AWS_SECRET_ACCESS_KEY": AWS_SECRET,
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{port}",
        "AWS_CONFIG_FILE": str(tmp_path / "none"),
        "AWS_SHARED_CREDENTIALS_FILE": str(tmp_path / "none"),
    }
    try:
        import boto3

        boto3.client(
            "s3",
            endpoint_url=env["AWS_ENDPOINT_URL_S3"],
            aws_access_key_id=AWS_ID,
            aws_secret_access_key=AWS_SECRET,
            region_name="us-east-1",
        ).create_bucket(Bucket="lab")
        yield env
    finally:
        server.stop()


def test_s3_push_pull_with_credentials_from_the_environment(
    alice: Path, tmp_path: Path, s3_env: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = _assert_round_trip(alice, "s3://lab/shared", tmp_path, s3_env, monkeypatch)
    missing = _cli(s3_env, "pull", "s3://nobucket/x", "--store", str(tmp_path / "carol"))
    last = missing.stderr.strip().splitlines()[-1]
    assert missing.returncode == 2 and last.startswith("error: remote s3://nobucket/x"), last
    # The remote's own files: download the bucket and grep it too.
    import boto3

    client = boto3.client(
        "s3",
        endpoint_url=s3_env["AWS_ENDPOINT_URL_S3"],
        aws_access_key_id=AWS_ID,
        aws_secret_access_key=AWS_SECRET,
        region_name="us-east-1",
    )
    dump = tmp_path / "bucket"
    for obj in client.list_objects_v2(Bucket="lab")["Contents"]:
        target = dump / obj["Key"]
        target.parent.mkdir(parents=True, exist_ok=True)
        client.download_file("lab", obj["Key"], str(target))
    assert any(dump.rglob("manifest.json"))
    _no_secret_anywhere(
        out + missing.stdout + missing.stderr,
        [alice, tmp_path / "bob", dump],
        [AWS_ID, AWS_SECRET],
    )


# -- SFTP --------------------------------------------------------------------------------


@pytest.fixture
def sshd(tmp_path: Path) -> Iterator[tuple[int, dict[str, str]]]:
    pytest.importorskip("sshfs", reason="sshfs is not installed")
    if not Path(SSHD).is_file() or shutil.which("ssh-keygen") is None:
        pytest.skip("OpenSSH server not installed (make setup installs openssh-server)")
    if os.geteuid() != 0:
        pytest.skip("sshd needs root to start here")
    keys = tmp_path / "keys"
    keys.mkdir()
    for name in ("host", "client"):
        subprocess.run(
            ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(keys / name)], check=True
        )
    shutil.copy(keys / "client.pub", keys / "authorized_keys")
    port = _free_port()
    config = keys / "sshd_config"
    config.write_text(
        f"Port {port}\nListenAddress 127.0.0.1\nHostKey {keys / 'host'}\n"
        f"PidFile {keys / 'sshd.pid'}\nAuthorizedKeysFile {keys / 'authorized_keys'}\n"
        "PasswordAuthentication no\nKbdInteractiveAuthentication no\n"
        "PermitRootLogin prohibit-password\nStrictModes no\nUsePAM no\n"
        "Subsystem sftp internal-sftp\n"
    )
    Path("/run/sshd").mkdir(exist_ok=True)  # sshd's privilege-separation directory
    proc = subprocess.Popen(
        [SSHD, "-D", "-e", "-f", str(config)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    home = tmp_path / "home"
    (home / ".ssh").mkdir(parents=True)
    host_pub = (keys / "host.pub").read_text().split()
    (home / ".ssh" / "known_hosts").write_text(f"[127.0.0.1]:{port} {host_pub[0]} {host_pub[1]}\n")
    (home / ".ssh" / "config").write_text(
        f"Host 127.0.0.1\n  User root\n  IdentityFile {keys / 'client'}\n"
    )
    env = {**os.environ, "HOME": str(home)}
    env.pop("SSH_AUTH_SOCK", None)
    try:
        _wait_port(port, proc)
        yield port, env
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_sftp_push_pull_with_keys_from_ssh_config(
    alice: Path, tmp_path: Path, sshd: tuple[int, dict[str, str]], monkeypatch: pytest.MonkeyPatch
) -> None:
    port, env = sshd
    remote_dir = tmp_path / "nas"
    url = f"sftp://127.0.0.1:{port}{remote_dir}"
    # A folder that does not exist on the server is refused unless --create.
    res = _cli(env, "push", url, "--store", str(alice))
    assert res.returncode == 2 and not remote_dir.exists(), res.stderr
    assert f"push: folder '{remote_dir}' does not exist (pass --create" in res.stderr
    out = _assert_round_trip(alice, url, tmp_path, env, monkeypatch)
    assert sorted(p.parent.name for p in remote_dir.glob("*/*/manifest.json"))
    private = (tmp_path / "keys" / "client").read_text().splitlines()[1]
    _no_secret_anywhere(out, [alice, tmp_path / "bob", remote_dir], [private])


def test_a_password_in_the_url_is_never_printed(tmp_path: Path) -> None:
    secret = "hunter2SONARMAP"
    port = _free_port()  # nothing listens: the connection fails
    res = _cli(
        dict(os.environ),
        "pull",
        f"sftp://alice:{secret}@127.0.0.1:{port}/x",
        "--store",
        str(tmp_path / "s"),
    )
    assert res.returncode == 2, res.stderr
    assert secret not in res.stdout + res.stderr and "alice" not in res.stderr


# -- HTTP (read-only) ---------------------------------------------------------------------


def test_http_pull_from_a_static_web_server(alice: Path, tmp_path: Path) -> None:
    pytest.importorskip("aiohttp", reason="aiohttp is not installed")
    served = tmp_path / "www"
    push(ArtifactStore(alice), str(served), create=True)
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"],
        cwd=served,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_port(port, proc)
        url = f"http://127.0.0.1:{port}/"
        assert sorted(list_remote(url)) == sorted(
            f"{r.stage}/{r.key}" for r in ArtifactStore(alice).iter_artifacts()
        )
        refs = pull(ArtifactStore(tmp_path / "bob"), url, ["summary"])
        assert {r.stage for r in refs} == {"source", "double", "summary"}
        res = _cli(dict(os.environ), "push", url, "--store", str(alice))
        assert res.returncode == 2 and "read-only" in res.stderr, res.stderr
    finally:
        proc.terminate()
        proc.wait(timeout=10)
