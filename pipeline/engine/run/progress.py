"""Rich progress on stderr for stage runs: one line per stage, spinner while computing,
and a `warning:` line for each empty or collapsed output a stage reports."""

from __future__ import annotations

from types import TracebackType
from typing import Any

from sonarmap.pipeline.engine.run.planned import PlannedStage
from sonarmap.pipeline.engine.run.runner import StageResult

__all__ = ["StageProgress"]


class StageProgress:
    """Context manager giving `on_start`/`on_stage` callbacks for `execute`."""

    def __init__(self, enabled: bool = True) -> None:
        from rich.console import Console
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self._progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            disable=not enabled,
            transient=False,
        )
        self._tasks: dict[str, Any] = {}

    def on_start(self, item: PlannedStage) -> None:
        if not self._tasks:  # shown from the first stage: a run refused before has no bar
            self._progress.__enter__()
        verb = "cached" if item.hit else f"computing ({item.reason})"
        self._tasks[item.stage.name] = self._progress.add_task(
            f"{item.stage.name:<11} {verb}", total=1
        )

    def on_stage(self, result: StageResult) -> None:
        # Warnings show even with the progress disabled (`--quiet`), one line each.
        for line in result.warnings:
            self._progress.console.print(
                f"warning: {line}", markup=False, highlight=False, soft_wrap=True
            )
        task = self._tasks.get(result.stage)
        if task is None:
            return
        mark = "[green]✓[/]" if result.status == "computed" else "[blue]=[/]"
        self._progress.update(
            task,
            completed=1,
            description=f"{mark} {result.stage:<11} {result.status:<8} {result.seconds:7.2f} s  "
            f"{result.key[:12]}",
        )

    def __enter__(self) -> StageProgress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._tasks:
            self._progress.__exit__(exc_type, exc, tb)
