"""push/pull on a fresh machine with the shipped model, and what a hostile remote cannot do."""

from __future__ import annotations

import errno
import io
import json
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import torch
from test_engine_cache import run_toy
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import ArtifactCorrupt, StoreError
from sonarmap.pipeline.engine.hashing import sha256_file
from sonarmap.pipeline.engine.run.runner import DatasetSpec, plan
from sonarmap.pipeline.engine.share import pull_local, transfer
from sonarmap.pipeline.engine.share import push_pull as share
from sonarmap.pipeline.engine.share.push_pull import list_remote, pull, push
from sonarmap.pipeline.engine.share.transfer import TransferStats
from sonarmap.pipeline.engine.share.trust import TrustPolicy
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
from sonarmap.pipeline.graph import all_stages, extra_sections, pipeline_stages
from sonarmap.pipeline.training.model_cache import copy_verified
from sonarmap.pipeline.training.shipped import shipped_models, shipped_store

SHIPPED = "configs/model"


def _cli(*args: str) -> Any:
    return CliRunner().invoke(app, list(args))


def _one_error_line(res: Any, *needles: str) -> None:
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.output
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.fixture
def shipped_remote(tmp_path: Path) -> tuple[Path, Path]:
    """A fresh store holding only the real shipped model, pushed by the CLI to a remote."""
    bundled = shipped_store(SHIPPED)
    assert bundled is not None
    alice = tmp_path / "alice"
    copy_verified(next(bundled.iter_artifacts()), ArtifactStore(alice))
    remote = tmp_path / "remote"
    res = _cli(
        "push", str(remote), "--create", "--store", str(alice), "--model-cache", str(tmp_path / "c")
    )
    assert res.exit_code == 0, res.output
    return alice, remote


def test_shipped_model_pushes_and_pulls_on_a_fresh_machine(
    shipped_remote: tuple[Path, Path], tmp_path: Path
) -> None:
    alice, remote = shipped_remote
    res = _cli(
        "push",
        str(remote),
        "train",
        "--create",
        "--store",
        str(alice),
        "--model-cache",
        str(tmp_path),
    )
    assert res.exit_code == 0 and "0 files sent" in res.stdout, res.output
    res = _cli("pull", str(remote), "--store", str(tmp_path / "bob"), "--json")
    assert res.exit_code == 0, res.output
    ((stage, key, _),) = shipped_models(SHIPPED)
    assert json.loads(res.stdout)["pulled"] == [f"{stage}/{key}"]
    bob = ArtifactStore(tmp_path / "bob")
    ref = bob.get(stage, key)
    assert ref is not None
    bob.verify(ref)


def test_a_really_missing_upstream_is_still_an_error(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(b"x" * 64)
    run_toy(data, tmp_path / "a")
    shutil.rmtree(next((tmp_path / "a" / "double").iterdir()))
    with pytest.raises(StoreError, match=r"double/[0-9a-f]{12}: upstream artifact missing"):
        push(ArtifactStore(tmp_path / "a"), str(tmp_path / "r"), ["summary"], create=True)


def _reverse_class_names(model_dir: Path) -> None:
    """The QA attack: same weights, class names reversed, manifest sha256 updated."""
    blob = torch.load(model_dir / "model.pt", weights_only=True)
    blob["class_names"] = list(reversed(blob["class_names"]))
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    (model_dir / "model.pt").write_bytes(buffer.getvalue())
    manifest = json.loads((model_dir / "manifest.json").read_text())
    manifest["files"]["model.pt"] = {
        "sha256": sha256_file(model_dir / "model.pt"),
        "size": len(buffer.getvalue()),
    }
    (model_dir / "manifest.json").write_text(json.dumps(manifest))


def test_substituted_model_is_refused_unless_pinned_and_never_gets_the_honest_keys(
    shipped_remote: tuple[Path, Path], tmp_path: Path
) -> None:
    alice, remote = shipped_remote
    model_dir = next((remote / "train").iterdir())
    _reverse_class_names(model_dir)
    bob = tmp_path / "bob"
    res = _cli("pull", str(remote), "--store", str(bob))
    _one_error_line(res, "model.pt", "not pinned", "--trust-model")
    assert not (bob / "train").exists()
    sha = sha256_file(model_dir / "model.pt")
    res = _cli("pull", str(remote), "--store", str(bob), "--trust-model", sha)
    assert res.exit_code == 0, res.output
    # Trusted or not, the substituted model cannot reproduce the honest run's keys.
    from sonarmap.pipeline.engine.config.load import load_config

    config = load_config(all_stages(), None, [], extra_sections())
    spec = DatasetSpec(tmp_path / "rec.mcap", "f" * 64, lambda _s: None)
    keys = []
    for store in (alice, bob):
        ref = next(ArtifactStore(store).iter_artifacts())
        planned = plan(
            pipeline_stages(),
            config,
            spec,
            ArtifactStore(store),
            until="classify",
            external={"train": (pipeline_stages()[0], ref)},  # only the ref is read
            content_keyed=("train",),
        )
        keys.append({p.stage.name: p.key for p in planned})
    assert keys[0]["keyframes"] == keys[1]["keyframes"]
    assert keys[0]["classify"] != keys[1]["classify"]


def test_malicious_pickle_is_refused_at_pull_without_running_it(
    shipped_remote: tuple[Path, Path], tmp_path: Path
) -> None:
    _, remote = shipped_remote
    model_dir = next((remote / "train").iterdir())
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self) -> Any:
            return (Path.touch, (marker,))

    buffer = io.BytesIO()
    torch.save({"state_dict": Evil()}, buffer)
    (model_dir / "model.pt").write_bytes(buffer.getvalue())
    manifest = json.loads((model_dir / "manifest.json").read_text())
    sha = sha256_file(model_dir / "model.pt")
    manifest["files"]["model.pt"] = {"sha256": sha, "size": len(buffer.getvalue())}
    (model_dir / "manifest.json").write_text(json.dumps(manifest))
    res = _cli("pull", str(remote), "--store", str(tmp_path / "bob"), "--trust-model", sha)
    _one_error_line(res, "model.pt", "weights-only")
    assert not marker.exists()
    assert not (tmp_path / "bob" / "train").exists()


def _toy_remote(tmp_path: Path) -> tuple[ArtifactStore, Path]:
    data = tmp_path / "raw.bin"
    data.write_bytes(bytes(range(256)) * 64)
    run_toy(data, tmp_path / "alice")
    remote = tmp_path / "remote"
    push(ArtifactStore(tmp_path / "alice"), str(remote), create=True)
    return ArtifactStore(tmp_path / "alice"), remote


def _plant(remote: Path, source: Path, stage: str) -> None:
    """Copy an artifact under `stage`, with a manifest and recipe that say `stage`."""
    manifest = json.loads((source / "manifest.json").read_text())
    manifest["stage"] = stage
    manifest["recipe"]["stage"] = stage
    from sonarmap.pipeline.engine.hashing import recipe_key

    manifest["key"] = key = recipe_key(manifest["recipe"])
    dest = remote / stage / key
    shutil.copytree(source, dest)
    (dest / "manifest.json").write_text(json.dumps(manifest))


@pytest.mark.parametrize("stage", ["runs", "_hidden"])
def test_reserved_folders_are_never_a_pull_target(tmp_path: Path, stage: str) -> None:
    _, remote = _toy_remote(tmp_path)
    _plant(remote, next((remote / "summary").iterdir()), stage)
    bob = tmp_path / "bob"
    res = _cli("pull", str(remote), stage, "--store", str(bob))
    _one_error_line(res, "reserved")
    res = _cli("pull", str(remote), "--store", str(bob))  # pulling everything skips it
    assert res.exit_code == 0, res.output
    # nothing of the planted folder came over: `runs` holds only the pull's own record
    held = sorted(p.name for p in (bob / stage).iterdir()) if (bob / stage).exists() else []
    assert all(name.startswith("pull-") and name.endswith(".json") for name in held), held


def test_recipe_stage_must_match_the_manifest_and_path(tmp_path: Path) -> None:
    _, remote = _toy_remote(tmp_path)
    source = next((remote / "summary").iterdir())
    manifest = json.loads((source / "manifest.json").read_text())
    manifest["stage"] = "double"  # keep the summary recipe: its key still matches
    dest = remote / "double" / manifest["key"]
    shutil.copytree(source, dest)
    (dest / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ArtifactCorrupt, match="recipe is for stage 'summary'"):
        pull(ArtifactStore(tmp_path / "bob"), str(remote), ["double"])


def test_declared_size_is_a_hard_limit_while_streaming(tmp_path: Path) -> None:
    from fsspec.implementations.local import LocalFileSystem

    big = tmp_path / "big.bin"
    big.write_bytes(b"\0" * (3 << 20))
    dst = tmp_path / "out.bin"
    with pytest.raises(ArtifactCorrupt, match="larger than the 100 bytes"):
        transfer.download(LocalFileSystem(), str(big), dst, 100, "0" * 64, "f")
    assert dst.stat().st_size <= 100


def test_oversized_and_overdeclared_files_are_refused_at_pull(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, remote = _toy_remote(tmp_path)
    blob = next(remote.glob("double/*/d.bin"))
    with blob.open("ab") as f:
        f.write(b"\0" * (2 << 20))
    res = _cli("pull", str(remote), "--store", str(tmp_path / "bob"))
    _one_error_line(res, "d.bin", "larger than")
    monkeypatch.setenv("SONARMAP_MAX_FILE_BYTES", "1000")
    res = _cli("pull", str(remote), "--store", str(tmp_path / "bob"))
    _one_error_line(res, "over the 1000-byte limit")
    assert list(ArtifactStore(tmp_path / "bob").iter_artifacts()) == []


def _fail_after(monkeypatch: pytest.MonkeyPatch, n: int, err: BaseException) -> list[str]:
    """Make `upload` fail after `n` files have been sent (an interrupted push)."""
    sent: list[str] = []
    real = transfer.upload
    lock = threading.Lock()

    def flaky(fs: Any, src: Path, dst: str, *a: Any, **k: Any) -> bool:
        with lock:  # exactly `n` uploads start, whatever the pool's concurrency
            if len(sent) >= n:
                raise err
            sent.append(dst)
        return real(fs, src, dst, *a, **k)

    monkeypatch.setattr(share, "upload", flaky)
    return sent


def test_interrupted_push_resumes_without_resending_and_shows_nothing_partial(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    alice, _ = _toy_remote(tmp_path)
    remote = tmp_path / "remote2"
    sent = _fail_after(monkeypatch, 2, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        push(alice, str(remote), create=True)
    assert len(sent) == 2 and list_remote(str(remote)) == []
    monkeypatch.setattr(share, "upload", transfer.upload)
    stats = TransferStats()
    pushed = push(alice, str(remote), stats=stats, create=True)
    total = sum(len(alice.get(*a.split("/")).manifest["files"]) for a in pushed)  # type: ignore[union-attr]
    assert stats.skipped == 2 and stats.sent == total - 2
    assert sorted(list_remote(str(remote))) == sorted(pushed)


_KILLED_PUSH = """
import os, signal, sys
from pathlib import Path
from sonarmap.pipeline.engine.share import push_pull as share, transfer
from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore
real, sent = share.upload, []
def upload(*a, **k):
    if len(sent) == 3:
        os.kill(os.getpid(), signal.SIGKILL)  # no cleanup, no finally: a real kill -9
    sent.append(1)
    return real(*a, **k)
share.upload = upload
transfer.WORKERS = 1  # one file at a time: exactly three are complete
share.push(ArtifactStore(Path(sys.argv[1])), sys.argv[2], create=True)
"""


def test_push_killed_with_sigkill_resumes_without_resending(tmp_path: Path) -> None:
    import subprocess
    import sys

    alice, _ = _toy_remote(tmp_path)
    remote = tmp_path / "remote2"
    root = Path(__file__).resolve().parents[1]
    killed = subprocess.run(
        [sys.executable, "-c", _KILLED_PUSH, str(alice.root), str(remote)],
        env={**os.environ, "PYTHONPATH": str(root)},
        capture_output=True,
        timeout=120,
    )
    assert killed.returncode == -9, killed.stderr
    assert list_remote(str(remote)) == []
    assert len([p for p in remote.rglob("*") if p.is_file()]) == 3
    stats = TransferStats()
    pushed = push(alice, str(remote), stats=stats, create=True)
    total = sum(len(alice.get(*a.split("/")).manifest["files"]) for a in pushed)  # type: ignore[union-attr]
    assert stats.skipped == 3 and stats.sent == total - 3


def test_reader_never_sees_a_partial_artifact_during_a_push(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    alice, _ = _toy_remote(tmp_path)
    remote = tmp_path / "remote2"
    real = transfer.upload

    def slow(*a: Any, **k: Any) -> bool:
        time.sleep(0.05)
        return real(*a, **k)

    monkeypatch.setattr(share, "upload", slow)
    seen: list[str] = []
    partial: list[str] = []
    done = threading.Event()

    def reader() -> None:
        while not done.is_set():
            for address in list_remote(str(remote)):
                seen.append(address)
                manifest = json.loads((remote / address / "manifest.json").read_text())
                for rel, entry in manifest["files"].items():
                    f = remote / address / rel
                    if not f.is_file() or f.stat().st_size != entry["size"]:
                        partial.append(f"{address}/{rel}")

    thread = threading.Thread(target=reader)
    thread.start()
    try:
        push(alice, str(remote), create=True)
    finally:
        done.set()
        thread.join()
    assert partial == []
    assert len(list_remote(str(remote))) == len(list(alice.iter_artifacts()))


def test_full_disk_on_push_exits_2_naming_the_path_and_leaves_nothing_visible(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _toy_remote(tmp_path)
    remote = tmp_path / "remote2"
    _fail_after(monkeypatch, 1, OSError(errno.ENOSPC, "No space left on device"))
    res = _cli("push", str(remote), "--create", "--store", str(tmp_path / "alice"))
    _one_error_line(res, str(remote), "No space left on device")
    assert list_remote(str(remote)) == []


def test_read_only_store_on_pull_exits_2_naming_the_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, remote = _toy_remote(tmp_path)
    bob = tmp_path / "bob"

    def refuse(self: Any, prefix: str) -> Path:
        raise OSError(errno.EROFS, "Read-only file system", str(bob / ".tmp"))

    monkeypatch.setattr(ArtifactStore, "tmp_path", refuse)
    res = _cli("pull", str(remote), "--store", str(bob))
    _one_error_line(res, str(bob), "Read-only file system")


def test_trust_policy_refuses_a_bad_pin() -> None:
    with pytest.raises(StoreError, match="not a sha256"):
        TrustPolicy.build(["abc"])
    res = _cli("pull", "/nonexistent", "--trust-model", "x" * 500)
    _one_error_line(res, "not a sha256")
    assert len(res.stderr) < 200


def test_interrupted_pull_resumes_without_refetching_verified_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, remote = _toy_remote(tmp_path)
    bob = ArtifactStore(tmp_path / "bob")
    real = transfer.download
    fetched: list[str] = []
    lock = threading.Lock()

    def flaky(fs: Any, src: str, *a: Any, **k: Any) -> None:
        with lock:  # exactly two downloads start
            if len(fetched) >= 2:
                raise KeyboardInterrupt
            fetched.append(src)
        real(fs, src, *a, **k)

    monkeypatch.setattr(pull_local, "download", flaky)
    with pytest.raises(KeyboardInterrupt):
        pull(bob, str(remote))
    assert list(bob.iter_artifacts()) == []
    monkeypatch.setattr(pull_local, "download", real)
    stats = TransferStats()
    refs = pull(bob, str(remote), stats=stats)
    total = sum(len(r.manifest["files"]) for r in refs)
    # Files are cached by sha256, so identical files of two artifacts are fetched once.
    assert stats.skipped >= 2 and stats.sent <= total - 2 and stats.sent + stats.skipped == total
    assert not any((bob.root / share.PULL_CACHE).iterdir())  # resume copies are removed


def test_a_fifo_or_device_in_a_remote_is_refused_without_blocking(tmp_path: Path) -> None:
    from fsspec.implementations.local import LocalFileSystem

    fifo = tmp_path / "f.bin"
    os.mkfifo(fifo)
    # Should the check regress, a writer opening the FIFO later unblocks the reader.
    unblock = threading.Timer(10.0, lambda: fifo.open("wb").close())
    unblock.start()
    try:
        for src in (fifo, Path("/dev/zero")):
            with pytest.raises(ArtifactCorrupt, match="not a regular file"):
                transfer.download(LocalFileSystem(), str(src), tmp_path / "o", 1, "0" * 64, "f")
    finally:
        unblock.cancel()


def test_a_manifest_that_is_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    """A FIFO data file was refused, but `pull` waited forever on a FIFO manifest."""
    _, remote = _toy_remote(tmp_path)
    manifest = next((remote / "double").iterdir()) / "manifest.json"
    manifest.unlink()
    os.mkfifo(manifest)
    unblock = threading.Timer(10.0, lambda: manifest.open("wb").close())  # should it regress
    unblock.start()
    try:
        with pytest.raises(ArtifactCorrupt, match="manifest is not a regular file"):
            pull(ArtifactStore(tmp_path / "bob"), str(remote), ["double"])
    finally:
        unblock.cancel()
    assert list(ArtifactStore(tmp_path / "bob").iter_artifacts()) == []


def test_a_manifest_listing_none_of_a_stages_files_is_refused_at_pull(tmp_path: Path) -> None:
    """It was committed, passed `show --verify`, and failed only in the next stage."""
    from sonarmap.pipeline.engine.share.trust import TrustPolicy

    _, remote = _toy_remote(tmp_path)
    manifest_path = next((remote / "double").iterdir()) / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    manifest["files"] = {}
    manifest_path.write_text(json.dumps(manifest))
    policy = TrustPolicy.build(required={"double": frozenset({"d.bin"})})
    bob = ArtifactStore(tmp_path / "bob")
    with pytest.raises(ArtifactCorrupt, match=r"manifest lists no 'd\.bin', which every double"):
        pull(bob, str(remote), ["double"], policy=policy)
    assert list(bob.iter_artifacts()) == []


@pytest.mark.parametrize(
    ("variable", "value"),
    [
        ("SONARMAP_MAX_FILE_BYTES", "-1"),
        ("SONARMAP_MAX_FILE_BYTES", "10GB"),
        ("SONARMAP_MAX_FILE_BYTES", "1e9"),
        ("SONARMAP_REMOTE_TIMEOUT_S", "abc"),
        ("SONARMAP_REMOTE_TIMEOUT_S", "0"),
        ("SONARMAP_REMOTE_TIMEOUT_S", "nan"),
    ],
)
def test_a_sharing_limit_that_is_not_a_number_is_refused_not_ignored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, variable: str, value: str
) -> None:
    """A user who tightened a limit got the default (64 GiB, 15 s) without a word."""
    _, remote = _toy_remote(tmp_path)
    monkeypatch.setenv(variable, value)
    for args in (("pull", str(remote)), ("push", str(remote))):
        res = _cli(*args, "--store", str(tmp_path / "bob"))
        _one_error_line(res, f"{variable}='{value}'")
    bob = tmp_path / "bob"
    assert not bob.exists() or list(ArtifactStore(bob).iter_artifacts()) == []
