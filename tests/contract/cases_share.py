"""Sharing cases: push on a fresh machine, and hostile remotes (file:// in the work dir).

A remote is built from a real run of the tiny mission with the shipped classifier (made
once into `data/qa/`), then edited the way an attacker or a broken disk would.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.contract.case import Case, names
from tests.fixtures import CACHE, cached_run, sonarmap

RUN = CACHE / "share-run"
SECRET = "hunter2QAsecret"


def _cached_run() -> Path:
    """A work dir after `sonarmap run rec.mcap` and `push remote` (made once per code version)."""
    return cached_run(RUN.name, [["push", "--create", "remote"]])


def _fresh_run(work: Path) -> None:
    run = _cached_run()
    shutil.copyfile(run / "rec.mcap", work / "rec.mcap")
    shutil.copytree(run / "data", work / "data")


def _remote(work: Path) -> Path:
    shutil.copytree(_cached_run() / "remote", work / "remote")
    return work / "remote"


def _artifact(remote: Path, stage: str) -> Path:
    return next(p for p in (remote / stage).iterdir() if (p / "manifest.json").is_file())


def _edit_manifest(directory: Path, change: Callable[[dict[str, Any]], None]) -> None:
    doc = json.loads((directory / "manifest.json").read_text())
    change(doc)
    (directory / "manifest.json").write_text(json.dumps(doc))


def _rehash(directory: Path, name: str) -> None:
    """Update the manifest's sha256 and size of `name` (the attacker controls both)."""
    import hashlib

    data = (directory / name).read_bytes()

    def set_entry(doc: dict[str, Any]) -> None:
        doc["files"][name] = {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}

    _edit_manifest(directory, set_entry)


def _no_store_dir(*names: str) -> Callable[[Path, Any], str | None]:
    def check(work: Path, _done: Any) -> str | None:
        for name in names:
            folder = work / "data" / "store" / name
            # a pull's own record (runs/pull-*.json) is the store's, not the remote's
            held = sorted(folder.iterdir()) if folder.is_dir() else [folder] * folder.exists()
            planted = [p for p in held if not (p.is_file() and p.name.startswith("pull-"))]
            if planted:
                return f"data/store/{name} was written ({planted[0].name})"
        return None

    return check


# -- sharing: a fresh machine's push and pull ------------------------------------------------


def _push(*targets: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        _fresh_run(work)
        return ["push", "--create", str(work / "out"), *targets]

    return build


def _pull_fresh(work: Path) -> list[str]:
    _remote(work)
    return ["pull", str(work / "remote"), "--store", str(work / "fresh")]


def _pulled_everything(work: Path, _done: Any) -> str | None:
    theirs = sorted(p.parent.name for p in (work / "remote").glob("*/*/manifest.json"))
    ours = sorted(p.parent.name for p in (work / "fresh").glob("*/*/manifest.json"))
    return None if ours == theirs else f"pulled {len(ours)} of {len(theirs)} artifacts"


def _push_again(work: Path) -> list[str]:
    _fresh_run(work)
    _remote(work)
    return ["push", str(work / "remote"), "--json"]


def _sent_nothing(work: Path, done: Any) -> str | None:
    doc = json.loads(done.stdout)
    return None if doc["files_sent"] == 0 else f"re-sent {doc['files_sent']} files"


def _resume_partial(work: Path) -> list[str]:
    """A push killed midway: files without manifests at the remote."""
    _fresh_run(work)
    remote = _remote(work)
    for manifest in list(remote.glob("*/*/manifest.json"))[::2]:
        manifest.unlink()
    return ["push", str(remote), "--json"]


def _resumed(work: Path, done: Any) -> str | None:
    doc = json.loads(done.stdout)
    if doc["files_sent"] != 0 or doc["files_already_there"] == 0:
        return f"sent {doc['files_sent']}, reused {doc['files_already_there']}"
    return None


def _cli(work: Path, *args: str) -> None:
    sonarmap(work, *args)


def _run_after_pull(work: Path) -> list[str]:
    """A fresh machine (empty caches) pulls a colleague's run, then runs it."""
    shutil.copyfile(_cached_run() / "rec.mcap", work / "rec.mcap")
    _cli(work, "pull", str(_remote(work)))
    return ["run", "rec.mcap", "--json"]


def _computed_nothing(work: Path, done: Any) -> str | None:
    computed = [s["stage"] for s in json.loads(done.stdout)["stages"] if s["status"] != "hit"]
    return f"computed {computed}" if computed else None


def _pinned_substitute(settings_too: bool) -> Callable[[Path], list[str]]:
    """The user pins a substituted model (its settings.json edited to match, or not)."""

    def build(work: Path) -> list[str]:
        shutil.copyfile(_cached_run() / "rec.mcap", work / "rec.mcap")
        _reversed_classes(work)
        model = _artifact(work / "remote", "train")
        if settings_too:
            settings = json.loads((model / "settings.json").read_text())
            settings["class_names"] = list(reversed(settings["class_names"]))
            (model / "settings.json").write_text(json.dumps(settings))
            _rehash(model, "settings.json")
        sha = json.loads((model / "manifest.json").read_text())["files"]["model.pt"]["sha256"]
        _cli(work, "pull", str(work / "remote"), "train", "--trust-model", sha)
        return ["run", "rec.mcap", "--json"]

    return build


def _not_the_honest_keys(work: Path, done: Any) -> str | None:
    honest = {p.parent.name for p in (_cached_run() / "remote").glob("*/*/manifest.json")}
    stages = json.loads(done.stdout)["stages"]
    same = [
        s["stage"] for s in stages if s["stage"] in ("classify", "evaluate") and s["key"] in honest
    ]
    return f"{same} kept the honest keys" if same else None


def _push_to_http(work: Path) -> list[str]:
    _fresh_run(work)
    return ["push", "http://127.0.0.1:9/remote"]


def _password_url(work: Path) -> list[str]:
    return ["pull", f"sftp://qa:{SECRET}@127.0.0.1:9/srv"]


def _no_secret(work: Path, done: Any) -> str | None:
    return "password printed" if SECRET in done.stdout + done.stderr else None


def _push_onto_a_file(work: Path) -> list[str]:
    _fresh_run(work)
    (work / "remote").write_text("not a directory")
    return ["push", str(work / "remote")]


def _pull_missing_remote(work: Path) -> list[str]:
    return ["pull", str(work / "nowhere")]


def _push_missing_upstream(work: Path) -> list[str]:
    _fresh_run(work)
    shutil.rmtree(_artifact(work / "data" / "store", "fuse"))
    return ["push", "--create", str(work / "out"), "evaluate"]


# -- trust -----------------------------------------------------------------------------------


def _reversed_classes(work: Path) -> list[str]:
    import torch

    model = _artifact(_remote(work), "train")
    blob = torch.load(model / "model.pt", weights_only=True)
    blob["class_names"] = list(reversed(blob["class_names"]))
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    (model / "model.pt").write_bytes(buffer.getvalue())
    _rehash(model, "model.pt")
    return ["pull", str(work / "remote")]


def _junk_model(work: Path) -> list[str]:
    model = _artifact(_remote(work), "train")
    (model / "model.pt").write_bytes(b"PK\x03\x04" + os.urandom(4000))
    _rehash(model, "model.pt")
    return ["pull", str(work / "remote"), "train"]


def _pickle_model(work: Path) -> list[str]:
    """A model.pt whose pickle runs code, pinned by the user: still refused at pull."""
    model = _artifact(_remote(work), "train")
    marker = work / "pwned"
    code = (
        "import io, pathlib, torch\n"
        "class Evil:\n"
        f"    def __reduce__(self): return (pathlib.Path.touch, (pathlib.Path({str(marker)!r}),))\n"
        "b = io.BytesIO(); torch.save({'state_dict': Evil()}, b)\n"
        f"open({str(model / 'model.pt')!r}, 'wb').write(b.getvalue())\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    _rehash(model, "model.pt")
    sha = json.loads((model / "manifest.json").read_text())["files"]["model.pt"]["sha256"]
    return ["pull", str(work / "remote"), "train", "--trust-model", sha]


def _not_pwned(work: Path, _done: Any) -> str | None:
    return "the pickle ran" if (work / "pwned").exists() else None


def _forged_recipe(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    _edit_manifest(fuse, lambda d: d["recipe"]["config"].update({"forged": 1}))
    return ["pull", str(work / "remote"), "fuse"]


def _other_stage_recipe(work: Path) -> list[str]:
    remote = _remote(work)
    src = _artifact(remote, "fuse")
    dest = remote / "features" / src.name
    shutil.copytree(src, dest)
    _edit_manifest(dest, lambda d: d.update({"stage": "features"}))
    return ["pull", str(remote), "features"]


def _plant(stage: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        from sonarmap.pipeline.engine.hashing import recipe_key

        remote = _remote(work)
        src = _artifact(remote, "fuse")
        doc = json.loads((src / "manifest.json").read_text())
        doc["stage"] = doc["recipe"]["stage"] = stage
        doc["key"] = recipe_key(doc["recipe"])
        dest = remote / stage / doc["key"]
        shutil.copytree(src, dest)
        (dest / "manifest.json").write_text(json.dumps(doc))
        return ["pull", str(remote), stage]

    return build


def _upstream_into_runs(work: Path) -> list[str]:
    remote = _remote(work)
    fuse = _artifact(remote, "fuse")
    _edit_manifest(fuse, lambda d: d["input_artifacts"].update({"features.x": "runs/abcdef"}))
    return ["pull", str(remote), "fuse"]


def _no_recipe(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    _edit_manifest(fuse, lambda d: d.pop("recipe"))
    return ["pull", str(work / "remote"), "fuse"]


def _escaping_path(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    entry = {"sha256": "0" * 64, "size": 1}
    _edit_manifest(fuse, lambda d: d["files"].update({"../../../../escape.txt": entry}))
    return ["pull", str(work / "remote"), "fuse"]


def _bad_pin(work: Path) -> list[str]:
    _remote(work)
    return ["pull", str(work / "remote"), "--trust-model", "x" * 5000]


def _all_skips_runs(work: Path) -> list[str]:
    _plant("runs")(work)
    return ["pull", str(work / "remote")]


# -- resources -------------------------------------------------------------------------------


def _lying_size(work: Path) -> list[str]:
    """A 3 GB (sparse) file listed as 100 bytes: refused after one chunk."""
    fuse = _artifact(_remote(work), "fuse")
    name = next(n for n in json.loads((fuse / "manifest.json").read_text())["files"])
    with (fuse / name).open("r+b") as f:
        f.truncate(3 << 30)
    _edit_manifest(fuse, lambda d: d["files"][name].update({"size": 100}))
    return ["pull", str(work / "remote"), "fuse"]


def _declared_petabyte(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    name = next(n for n in json.loads((fuse / "manifest.json").read_text())["files"])
    _edit_manifest(fuse, lambda d: d["files"][name].update({"size": 10**15}))
    return ["pull", str(work / "remote"), "fuse"]


def _huge_manifest(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    _edit_manifest(fuse, lambda d: d.update({"padding": "x" * (40 << 20)}))
    return ["pull", str(work / "remote"), "fuse"]


def _nested_manifest(work: Path) -> list[str]:
    fuse = _artifact(_remote(work), "fuse")
    (fuse / "manifest.json").write_text("[" * 200_000 + "]" * 200_000)
    return ["pull", str(work / "remote"), "fuse"]


def _special_file(kind: str) -> Callable[[Path], list[str]]:
    """A listed file that is a FIFO (an open would block) or a link to /dev/zero."""

    def build(work: Path) -> list[str]:
        fuse = _artifact(_remote(work), "fuse")
        name = next(n for n in json.loads((fuse / "manifest.json").read_text())["files"])
        (fuse / name).unlink()
        if kind == "fifo":
            os.mkfifo(fuse / name)
        else:
            (fuse / name).symlink_to("/dev/zero")
        return ["pull", str(work / "remote"), "fuse"]

    return build


def _small_cap(work: Path) -> list[str]:
    _remote(work)
    return ["pull", str(work / "remote")]


def _no_big_file(work: Path, _done: Any) -> str | None:
    for f in (work / "data").rglob("*") if (work / "data").exists() else []:
        if f.is_file() and f.stat().st_size > 10 << 20:
            return f"{f} has {f.stat().st_size} bytes"
    return None


CASES = [
    Case("sharing", "push of a fresh run (shipped model) with upstream", _push(), (0,)),
    *[
        Case("sharing", f"push {stage} of a fresh run", _push(stage), (0,))
        for stage in ("voxelize", "classify", "evaluate", "train")
    ],
    Case(
        "sharing",
        "pull of a whole remote into a fresh store",
        _pull_fresh,
        (0,),
        _pulled_everything,
    ),
    Case("sharing", "push again sends nothing", _push_again, (0,), _sent_nothing),
    Case(
        "sharing",
        "a fresh store that pulled a run computes nothing",
        _run_after_pull,
        (0,),
        _computed_nothing,
        max_seconds=60,
    ),
    Case("sharing", "push resumes an interrupted push", _resume_partial, (0,), _resumed),
    Case("sharing", "push to a read-only http remote", _push_to_http),
    Case("sharing", "sftp URL with a password, unreachable", _password_url, (2,), _no_secret),
    Case("sharing", "push onto a path that is a file", _push_onto_a_file),
    Case("sharing", "pull from a missing remote", _pull_missing_remote),
    Case("sharing", "push with an upstream artifact really missing", _push_missing_upstream),
    Case("trust", "model with class_names reversed, sha256 updated", _reversed_classes),
    Case("trust", "model.pt of random bytes after zip magic, sha256 updated", _junk_model),
    Case("trust", "model.pt with a code-running pickle, pinned", _pickle_model, (2,), _not_pwned),
    Case(
        "trust",
        "a pinned substitute model gets other classify/evaluate keys",
        _pinned_substitute(settings_too=True),
        (0,),
        _not_the_honest_keys,
        max_seconds=120,
    ),
    Case(
        "trust",
        "a pinned model.pt whose settings.json still names the honest classes",
        _pinned_substitute(settings_too=False),
        (2,),
        names("model.pt", "settings.json"),
        max_seconds=120,
    ),
    Case("trust", "recipe edited, key kept", _forged_recipe),
    Case("trust", "fuse recipe under features/", _other_stage_recipe),
    Case("trust", "manifest with stage runs", _plant("runs"), (2,), _no_store_dir("runs")),
    Case(
        "trust", "manifest with stage _private", _plant("_private"), (2,), _no_store_dir("_private")
    ),
    Case("trust", "pull all skips a planted runs/", _all_skips_runs, (0,), _no_store_dir("runs")),
    Case("trust", "upstream address into runs/", _upstream_into_runs),
    Case("trust", "manifest without recipe", _no_recipe),
    Case("trust", "file path escaping the artifact", _escaping_path),
    Case("trust", "a 5000-character --trust-model", _bad_pin),
    Case("resources", "3 GB file listed as 100 bytes", _lying_size, (2,), _no_big_file),
    Case("resources", "file declaring 1 PB", _declared_petabyte),
    Case("resources", "40 MB manifest", _huge_manifest),
    Case("resources", "a listed file that is a FIFO", _special_file("fifo")),
    Case(
        "resources", "a listed file linked to /dev/zero", _special_file("zero"), (2,), _no_big_file
    ),
    Case("resources", "manifest nested 200,000 deep", _nested_manifest),
    Case(
        "resources",
        "files over SONARMAP_MAX_FILE_BYTES",
        _small_cap,
        env={"SONARMAP_MAX_FILE_BYTES": "1000"},
    ),
]
