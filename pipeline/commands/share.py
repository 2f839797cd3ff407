"""`sonarmap push|pull REMOTE [KEY...]`: share artifacts through any fsspec URL."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from sonarmap.pipeline.commands._common import JSON_OPT, STORE_OPT, emit_json
from sonarmap.pipeline.training.model_cache import DEFAULT_MODEL_CACHE

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.share.trust import TrustPolicy
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

__all__ = ["pull", "push", "register"]

_UPSTREAM = typer.Option(True, "--upstream/--no-upstream", help="Include upstream artifacts.")
_REMOTE = typer.Argument(
    ..., help="Directory, s3://bucket/path, sftp://host/path, or http(s):// (pull only)."
)


def _policy(pins: list[str], cache: ArtifactStore | None) -> TrustPolicy:
    """Shipped models (leaves, pinned), models trained in the model cache, and the user's pins."""
    from sonarmap.pipeline.engine.share.trust import TrustPolicy, env_pins
    from sonarmap.pipeline.graph import required_files
    from sonarmap.pipeline.training.config import TrainingDataConfig
    from sonarmap.pipeline.training.shipped import shipped_models

    local = []
    if cache is not None and (cache.root / "train").is_dir():
        local = [
            TrustPolicy.model_sha(r.manifest) for r in cache.iter_artifacts() if r.stage == "train"
        ]
    shipped = shipped_models(TrainingDataConfig().shipped_models)
    return TrustPolicy.build([*pins, *env_pins(), *filter(None, local)], shipped, required_files())


def _check_environment() -> None:
    """The sharing limits a user set in the environment, checked before any transfer (a
    bad one is one line naming the variable, exit 2)."""
    from sonarmap.pipeline.engine.share.remotes import remote_timeout_s
    from sonarmap.pipeline.engine.share.transfer import max_file_bytes

    remote_timeout_s()
    max_file_bytes()


def push(
    remote: str = _REMOTE,
    targets: list[str] | None = typer.Argument(None, help="Stage names or key prefixes."),
    store: Path = STORE_OPT,
    upstream: bool = _UPSTREAM,
    model_cache: Path = typer.Option(
        DEFAULT_MODEL_CACHE,
        "--model-cache",
        help="Model cache (`<training.directory>/store`) holding a model's training data.",
    ),
    create: bool = typer.Option(
        False,
        "--create",
        help="Create the bucket (s3://, gs://) or folder (a path, sftp://) if it is missing.",
    ),
    json_: bool = JSON_OPT,
) -> None:
    """Copy artifacts (and by default everything upstream of them) to REMOTE.

    A shipped model is sent without its training data (its lock is its provenance);
    files already at REMOTE with the right sha256 are not sent again.
    """
    from sonarmap.pipeline.engine.share.push_pull import push as do_push

    _check_environment()
    from sonarmap.pipeline.engine.share.remotes import display
    from sonarmap.pipeline.engine.share.transfer import TransferStats
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    stats = TransferStats()
    cache = ArtifactStore(model_cache)
    pushed = do_push(
        ArtifactStore(store),
        remote,
        targets or (),
        with_upstream=upstream,
        fallbacks=[cache],
        policy=_policy([], None),
        stats=stats,
        create=create,
    )
    if json_:
        emit_json(
            {
                "remote": display(remote),
                "pushed": pushed,
                "files_sent": stats.sent,
                "files_already_there": stats.skipped,
                "bytes_sent": stats.bytes,
            }
        )
    else:
        typer.echo(
            f"pushed {len(pushed)} artifacts to {display(remote)} "
            f"({stats.sent} files sent, {stats.skipped} already there)"
        )


def pull(
    remote: str = _REMOTE,
    targets: list[str] | None = typer.Argument(None, help="Stage names or key prefixes."),
    store: Path = STORE_OPT,
    upstream: bool = _UPSTREAM,
    trust_model: list[str] | None = typer.Option(
        None,
        "--trust-model",
        help="sha256 of a model.pt to accept (besides the shipped model). Repeatable; "
        "also SONARMAP_TRUSTED_MODELS.",
    ),
    model_cache: Path = typer.Option(
        DEFAULT_MODEL_CACHE,
        "--model-cache",
        help="Model cache: models trained there are trusted.",
    ),
    json_: bool = JSON_OPT,
) -> None:
    """Fetch artifacts from REMOTE, verifying keys and sha256s before committing.

    A model is accepted only when its sha256 is pinned: the shipped model's, one
    trained in the model cache, or one given with --trust-model.
    """
    from sonarmap.pipeline.engine.share.push_pull import pull as do_pull

    _check_environment()
    from sonarmap.pipeline.engine.share.remotes import display
    from sonarmap.pipeline.engine.share.transfer import TransferStats
    from sonarmap.pipeline.engine.store.artifact_store import ArtifactStore

    stats = TransferStats()
    refs = do_pull(
        ArtifactStore(store),
        remote,
        targets or (),
        with_upstream=upstream,
        policy=_policy(trust_model or [], ArtifactStore(model_cache)),
        stats=stats,
    )
    if json_:
        emit_json(
            {
                "remote": display(remote),
                "pulled": [f"{r.stage}/{r.key}" for r in refs],
                "bytes_received": stats.bytes,
            }
        )
    else:
        typer.echo(f"pulled {len(refs)} artifacts from {display(remote)}")


def register(app: typer.Typer) -> None:
    app.command("push")(push)
    app.command("pull")(pull)
