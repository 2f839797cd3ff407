"""Push and pull of a store of >= 100 MB through each remote kind: time and MB/s.

    .venv/bin/python benchmarks/bench_share.py [--mb 128] [--work data/bench/share]

A synthetic store of `--mb` MB (8 artifacts, each one large random file plus two small
ones) is pushed to and pulled back from:

- file: a local directory;
- s3: moto's standalone server on 127.0.0.1 (as in `tests/test_share_remotes.py`);
- sftp: an OpenSSH sshd on 127.0.0.1 with throwaway keys (needs root and sshd);
- http: pull only, from `python -m http.server` serving the file remote.

Each pull goes into a fresh store and verifies every sha256 (while streaming, then again
before the commit), so pull MB/s include hashing. A server that cannot start here is
reported as skipped.

Measured 2026-12-02 (134.2 MB, 2 cores shared with other jobs): file push 1.43 s
(93.9 MB/s), pull 3.15 s (42.6 MB/s); s3 (moto) push 5.16 s (26.0 MB/s), pull 4.67 s
(28.7 MB/s); sftp (local sshd) push 3.66 s (36.7 MB/s), pull 6.01 s (22.3 MB/s); http
pull 2.71 s (49.5 MB/s).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

from sonarmap.pipeline.engine.hashing import recipe_key  # noqa: E402
from sonarmap.pipeline.engine.share.push_pull import pull, push  # noqa: E402
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore  # noqa: E402


def make_store(root: Path, total_mb: int, n: int = 8) -> int:
    """`n` artifacts of random bytes, `total_mb` MB in all; returns the byte count."""
    store = ArtifactStore(root)
    size = total_mb * (1 << 20) // n
    for i in range(n):
        recipe = {"stage": "blob", "version": 1, "index": i, "mb": total_mb}
        key = recipe_key(recipe)

        def build(tmp: Path, i: int = i) -> dict[str, Any]:
            (tmp / "data.bin").write_bytes(os.urandom(size))
            (tmp / "meta.json").write_text(json.dumps({"i": i}))
            (tmp / "notes.txt").write_text("x" * 1000)
            return {}

        store.commit("blob", key, build, {"recipe": recipe})
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(port: int) -> None:
    for _ in range(200):
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise RuntimeError(f"nothing on port {port}")


@contextmanager
def s3_remote(work: Path) -> Iterator[str]:
    import boto3
    from moto.server import ThreadedMotoServer

    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    os.environ.update(
        {
            "AWS_ACCESS_KEY_ID": "bench",
            "AWS_SECRET_ACCESS_KEY": "bench",
            "AWS_DEFAULT_REGION": "us-east-1",
            "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{port}",
        }
    )
    try:
        boto3.client("s3", endpoint_url=f"http://127.0.0.1:{port}").create_bucket(Bucket="bench")
        yield "s3://bench/store"
    finally:
        server.stop()


@contextmanager
def sftp_remote(work: Path) -> Iterator[str]:
    keys = work / "ssh"
    shutil.rmtree(keys, ignore_errors=True)
    keys.mkdir(parents=True)
    for name in ("host", "client"):
        subprocess.run(
            ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(keys / name)], check=True
        )
    shutil.copy(keys / "client.pub", keys / "authorized_keys")
    port = _free_port()
    (keys / "cfg").write_text(
        f"Port {port}\nListenAddress 127.0.0.1\nHostKey {keys / 'host'}\nPidFile {keys / 'pid'}\n"
        f"AuthorizedKeysFile {keys / 'authorized_keys'}\nPasswordAuthentication no\n"
        "PermitRootLogin prohibit-password\nStrictModes no\nUsePAM no\nSubsystem sftp internal-sftp\n"
    )
    Path("/run/sshd").mkdir(exist_ok=True)
    proc = subprocess.Popen(["/usr/sbin/sshd", "-D", "-f", str(keys / "cfg")])
    home = keys / "home"
    (home / ".ssh").mkdir(parents=True)
    pub = (keys / "host.pub").read_text().split()
    (home / ".ssh" / "known_hosts").write_text(f"[127.0.0.1]:{port} {pub[0]} {pub[1]}\n")
    (home / ".ssh" / "config").write_text(
        f"Host 127.0.0.1\n  User root\n  IdentityFile {keys / 'client'}\n"
    )
    old_home = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    try:
        _wait(port)
        yield f"sftp://127.0.0.1:{port}{work / 'sftp-remote'}"
    finally:
        proc.terminate()
        proc.wait()
        if old_home is not None:
            os.environ["HOME"] = old_home


@contextmanager
def file_remote(work: Path) -> Iterator[str]:
    yield str(work / "file-remote")


@contextmanager
def http_remote(work: Path) -> Iterator[str]:
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"],
        cwd=work / "file-remote",
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait(port)
        yield f"http://127.0.0.1:{port}/"
    finally:
        proc.terminate()
        proc.wait()


def _timed(fn: Callable[[], Any]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=int, default=128)
    parser.add_argument("--work", type=Path, default=ROOT / "data" / "bench" / "share")
    parser.add_argument("--json", action="store_true")
    opts = parser.parse_args()
    import logging

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # moto's request log
    work = opts.work.resolve()
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    nbytes = make_store(work / "store", opts.mb)
    mb = nbytes / 1e6
    source = ArtifactStore(work / "store")
    results = []
    kinds: list[tuple[str, Callable[[Path], Any], bool]] = [
        ("file", file_remote, True),
        ("s3", s3_remote, True),
        ("sftp", sftp_remote, True),
        ("http", http_remote, False),
    ]
    for kind, remote_of, can_push in kinds:
        row: dict[str, Any] = {"remote": kind, "mb": round(mb, 1)}
        try:
            with remote_of(work) as remote:
                if can_push:
                    row["push_s"] = round(_timed(lambda r=remote: push(source, r, create=True)), 2)
                    row["push_mb_s"] = round(mb / row["push_s"], 1)
                dest = ArtifactStore(work / f"pulled-{kind}")
                row["pull_s"] = round(_timed(lambda r=remote, d=dest: pull(d, r)), 2)
                row["pull_mb_s"] = round(mb / row["pull_s"], 1)
        except Exception as err:  # a server that cannot start here is reported, not fatal
            row["skipped"] = f"{type(err).__name__}: {str(err)[:120]}"
        results.append(row)
        print(json.dumps(row) if opts.json else row, flush=True)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
