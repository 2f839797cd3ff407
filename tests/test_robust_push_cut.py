"""A connection cut in the middle of a push (issue 52, root 4): exit 2 with one line
naming the remote, the operation and the cause, no asyncio noise, and nothing on the
remote visible as complete that is not. S3 is moto's server behind a proxy (both on
127.0.0.1, started here) that cuts every connection once a given number of uploads began."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_robust_remotes import _cli, _one_error
from test_share_remotes import AWS_ID, AWS_SECRET, alice, s3_env  # noqa: F401 - fixtures

from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore


class _CuttingProxy:
    """Forwards 127.0.0.1:port to `upstream`; from the `cut_at`-th PUT on, resets every
    connection and refuses new ones (a link that drops, a server that dies), or with
    `silent` stops reading and answering while every connection stays open (a link that
    goes quiet: no reset ever reaches the client)."""

    def __init__(self, upstream: int, cut_at: int, silent: bool = False) -> None:
        self.upstream, self.cut_at, self.puts, self.silent = upstream, cut_at, 0, silent
        self.cut = threading.Event()
        self.lock = threading.Lock()
        self.conns: list[socket.socket] = []
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(32)
        self.port = int(self.sock.getsockname()[1])
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client = self.sock.accept()[0]
            except OSError:
                return
            server = socket.create_connection(("127.0.0.1", self.upstream))
            with self.lock:
                self.conns += [client, server]
                if self.cut.is_set():
                    if self.silent:
                        continue
                    self._reset()
                    return
            threading.Thread(target=self._pump, args=(client, server, True), daemon=True).start()
            threading.Thread(target=self._pump, args=(server, client, False), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, upload: bool) -> None:
        try:
            while data := src.recv(65536):
                with self.lock:
                    if upload and data.startswith(b"PUT "):
                        self.puts += 1
                        if self.puts >= self.cut_at:
                            self.cut.set()
                    if self.cut.is_set():
                        if not self.silent:
                            self._reset()
                        return  # silent: nothing more is read, sent or closed
                dst.sendall(data)
        except OSError:
            pass

    def _reset(self) -> None:
        """Close the listener, then every connection with an RST (as a dropped link or a
        killed server gives). Called with the lock held."""
        self.sock.close()
        for c in self.conns:
            try:
                c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                # shutdown first: a close alone leaves a socket that another thread is
                # reading from open and silent (a black hole, not a dropped link).
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()


@pytest.fixture
def client(s3_env: dict[str, str]) -> Iterator[object]:  # noqa: F811
    import boto3

    yield boto3.client(
        "s3",
        endpoint_url=s3_env["AWS_ENDPOINT_URL_S3"],
        aws_access_key_id=AWS_ID,
        aws_secret_access_key=AWS_SECRET,
        region_name="us-east-1",
    )


@pytest.mark.parametrize("cut_at", [2, 5])
def test_a_connection_cut_mid_push_is_one_line_and_leaves_nothing_half_visible(
    s3_env: dict[str, str],  # noqa: F811
    alice: Path,  # noqa: F811
    client: object,
    cut_at: int,
) -> None:
    upstream = int(s3_env["AWS_ENDPOINT_URL_S3"].rsplit(":", 1)[1])
    proxy = _CuttingProxy(upstream, cut_at)
    env = {
        **s3_env,
        "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{proxy.port}",
        "SONARMAP_REMOTE_TIMEOUT_S": "3",
    }
    # moto's state is the process's: a folder of its own per case.
    remote = f"s3://lab/cut{cut_at}"
    res = _cli(env, "push", remote, "--store", str(alice), timeout=90)
    assert proxy.cut.is_set(), res.stderr[-2000:]
    line = _one_error(res)
    assert f"error: remote {remote}: push: connection dropped" in line, line
    assert "Task exception was never retrieved" not in res.stderr + res.stdout
    # Every manifest on the remote has every file it lists, at its size.
    listed = client.list_objects_v2(Bucket="lab", Prefix=f"cut{cut_at}/")  # type: ignore[attr-defined]
    objects = {o["Key"]: o["Size"] for o in listed.get("Contents", [])}
    for key in [k for k in objects if k.endswith("/manifest.json")]:
        body = client.get_object(Bucket="lab", Key=key)["Body"].read()  # type: ignore[attr-defined]
        folder = key.rsplit("/", 1)[0]
        for rel, entry in json.loads(body)["files"].items():
            assert objects.get(f"{folder}/{rel}") == entry["size"], (key, rel)
    # And a push once the link is back finishes the job.
    res = _cli(s3_env, "push", remote, "--store", str(alice), timeout=90)
    assert res.returncode == 0, res.stderr[-2000:]
    listed = client.list_objects_v2(Bucket="lab", Prefix=f"cut{cut_at}/")  # type: ignore[attr-defined]
    assert sum(o["Key"].endswith("/manifest.json") for o in listed["Contents"]) == len(
        list(ArtifactStore(alice).iter_artifacts())
    )


@pytest.mark.realtime
def test_a_push_whose_link_goes_silent_ends_in_bounded_time(
    s3_env: dict[str, str],  # noqa: F811
    alice: Path,  # noqa: F811
) -> None:
    """No reset, no answer, the connection left open: the push must still end, with one
    line saying it timed out, within a deadline that grows only with the bytes sent."""
    upstream = int(s3_env["AWS_ENDPOINT_URL_S3"].rsplit(":", 1)[1])
    proxy = _CuttingProxy(upstream, 3, silent=True)
    env = {
        **s3_env,
        "AWS_ENDPOINT_URL_S3": f"http://127.0.0.1:{proxy.port}",
        "SONARMAP_REMOTE_TIMEOUT_S": "2",
    }
    t0 = time.monotonic()
    res = _cli(env, "push", "s3://lab/silent", "--store", str(alice), timeout=120)
    elapsed = time.monotonic() - t0
    assert proxy.cut.is_set(), res.stderr[-2000:]
    line = _one_error(res)
    assert "error: remote s3://lab/silent: push: timed out" in line, line
    # Each file has 4 timeouts plus its size at 64 KiB/s; files go four at a time, and the
    # first failure stops new ones: the push ends within about one largest file's deadline.
    largest = max(p.stat().st_size for p in alice.rglob("*") if p.is_file())
    assert elapsed < 4 * 2 + largest / (64 << 10) + 30, (elapsed, largest)
