"""A sweep's checks: its inputs before the first run, its exit status after the last."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import ConfigError, SourceError
from sonarmap.pipeline.experiments.sweep import RunOutcome, RunSpec

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.graph import Graph

__all__ = ["check_inputs", "failure_exit_code"]


def check_inputs(
    specs: Sequence[RunSpec],
    graph: Graph,
    check_references: Callable[[Any], None] = lambda config: None,
) -> None:
    """Refuse (exit 2) before the first run when a dataset or a config point is unusable.

    Every distinct (config file, overrides) point must load, and what it names outside
    itself must be there (`check_references(config)`, the CLI's: a model folder, a sonar
    preset), checked first; every
    dataset must exist and be readable as a recording (its files open, its format is
    recognised, its sonar and navigation topics are found under every point's
    `keyframes` settings). Raises `ConfigError` / `SourceError` naming the first bad one.
    """
    from sonarmap.pipeline.engine.config.load import load_config
    from sonarmap.pipeline.readers.pinned_calibration import pin_calibration

    # Config first (cheap, and what a typo in --set most likely is), with what each point
    # names outside itself (a model folder, a sonar preset), then datasets.
    readers: dict[str, Any] = {}  # each distinct keyframes section: how it reads a recording
    points: dict[str, tuple[str, ...]] = {}  # each point's keyed config: its overrides
    for config_path, args in dict.fromkeys((s.config_path, tuple(s.override_args)) for s in specs):
        path = Path(config_path) if config_path else None
        config = load_config(graph.config_stages, path, args, graph.extra_sections)
        check_references(config)
        section = getattr(config, "keyframes", None)
        readers.setdefault(repr(section), section)
        # Two files of the same content (a calibration copied) key the same runs.
        keyed = repr(pin_calibration(config).model_dump(mode="json"))
        if keyed in points:
            raise ConfigError(
                f"sweep: [{', '.join(points[keyed])}] and [{', '.join(args)}] are the same"
                " point (the files they name hold the same content): a repeated run would"
                " count as a replicate with a spread of 0"
            )
        points[keyed] = args
    for dataset in dict.fromkeys(s.dataset for s in specs):
        path = Path(dataset)
        if not path.exists():
            raise SourceError(f"{path}: no such file or directory")
        for part in graph.parts(path):
            try:
                with part.open("rb") as f:
                    f.read(16)
            except OSError as err:
                raise SourceError(f"{part}: cannot read ({err.strerror})") from err
        # Opening reads the topic list and finds the sonar and navigation topics: a
        # file with none of them is refused now, not after the other runs.
        for section in readers.values():
            graph.open(path, section)


def failure_exit_code(outcomes: Sequence[RunOutcome]) -> int:
    """The sweep's exit status: 0 when every run succeeded, 1 when any failed on a bug,
    else 2 (every failure was bad input)."""
    codes = {o.exit_code or 1 for o in outcomes if o.status != "ok"}
    if not codes:
        return 0
    return 1 if 1 in codes else 2
