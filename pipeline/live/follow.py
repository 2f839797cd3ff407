"""`sonarmap follow`'s loop: map a recording while it is written, until it is closed.

A poll every `poll_s` copies the recording's new complete records into a snapshot
(`growing.McapSnapshot`: a valid, closed MCAP of what has arrived). At most every
`every_s`, when something new arrived, the normal run maps the snapshot up to the map
(`MAP_STAGE`, no figures, the normal store, in this process) and the live feed publishes
each stage as it finishes, as `run --live` does. Each update is the engine's ordinary run on a new
dataset: whatever the store already holds for it (cached stages, per-keyframe work where
the stages keep it) is reused, and nothing here knows which.

The loop returns when the recording is closed (its footer and magic written), or after
`idle_timeout_s` without growth; the caller then runs the finished recording as `run` does.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.api import RunRequest, run_dataset
from sonarmap.pipeline.engine.errors import ConfigError, PipelineError
from sonarmap.pipeline.live.bag_snapshot import BagSnapshot
from sonarmap.pipeline.live.growing import Growth, McapSnapshot
from sonarmap.pipeline.live.preview import Anchor, Preview, anchor_of, unsaid

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.graph import Graph

__all__ = ["MAP_STAGE", "PREVIEW_TOPICS", "FollowOptions", "Follower", "Update"]

MAP_STAGE = "voxelize"
"""The last stage of an update: the map (evaluation and figures wait for the end)."""
PREVIEW_TOPICS = ("/map/preview", "/trajectory/preview")
"""The preview's topics (`sonarmap.pipeline.live.preview`)."""
WAITING_SAY_S = 10.0
"""A recording that stopped growing without being closed says what it waits for after this."""


@dataclass(frozen=True)
class FollowOptions:
    """How `follow` watches and maps.

    Attributes:
        every_s: least time between the starts of two map updates [s].
        poll_s: time between two looks at the recording's size [s].
        idle_timeout_s: end as if closed after this long without growth [s] (None: never).
    """

    every_s: float = 2.0
    poll_s: float = 0.25
    idle_timeout_s: float | None = None


@dataclass
class Update:
    """One map update.

    Attributes:
        number: 1, 2, ...
        read_bytes: bytes of the recording in the snapshot it mapped.
        keyframes: keyframes of its run (None when it made none).
        t_last_ns: log time of the newest keyframe (None: none).
        compute_s: wall time of the run and its publication [s].
        lag_s: from the arrival of the newest keyframe's data to its map published [s].
        voxels: the map's voxel counts ({} when it made no map).
        problem: why it made no map ("" when it did).
        warnings: the run's warnings (empty or collapsed outputs), counted.
        anchor: where the preview restarts from (None: no preview, or nothing to anchor).
    """

    number: int
    read_bytes: int
    keyframes: int | None = None
    t_last_ns: int | None = None
    compute_s: float = 0.0
    lag_s: float | None = None
    voxels: dict[str, int] = field(default_factory=dict)
    problem: str = ""
    warnings: int = 0
    anchor: Anchor | None = None

    def line(self) -> str:
        """The progress line `follow` prints on stderr."""
        head = f"follow: update {self.number}: {self.read_bytes / 1e6:.1f} MB read"
        if self.problem:
            return f"{head}, no map yet ({self.problem})"
        vox = ", ".join(f"{k} {v}" for k, v in sorted(self.voxels.items()))
        lag = "" if self.lag_s is None else f", lag {self.lag_s:.1f} s"
        warn = (
            f", {self.warnings} warnings on what has arrived (the final run says those that hold)"
            if self.warnings
            else ""
        )
        return (
            f"{head}, {self.keyframes} keyframes, map voxels: {vox or '-'}; "
            f"computed in {self.compute_s:.1f} s{lag}{warn}"
        )


class Follower:
    """Watches `request.dataset` (an MCAP file, or a rosbag2 directory of MCAP files,
    being written) and maps its snapshot.

    Args:
        request: the run asked for (dataset, config, store, workers).
        graph: the graph the CLI built.
        scratch: a private folder for the snapshot.
        on_stage: the live feed's `on_stage` (None: no live view).
        drain: waits until the feed published what it was given (None: no live view).
        publish: the live server's `submit` (None: no live view, no preview).
        say: prints one progress line.
        options: the timing options.
    """

    def __init__(
        self,
        request: RunRequest,
        graph: Graph,
        scratch: Path,
        *,
        on_stage: Callable[[Any], None] | None = None,
        drain: Callable[[], object] | None = None,
        publish: Callable[[tuple[str, ...], Callable[[], Any]], None] | None = None,
        say: Callable[[str], None] = print,
        options: FollowOptions = FollowOptions(),
    ) -> None:
        self.request = request
        self.graph = graph
        self.snapshot: McapSnapshot | BagSnapshot = (
            BagSnapshot(request.dataset, scratch)
            if request.dataset.is_dir()
            else McapSnapshot(request.dataset, scratch / "growing.mcap")
        )
        self.options = options
        self._on_stage, self._drain, self._say = on_stage, drain, say
        self._publish = publish
        self.preview: Preview | None = None
        if publish is not None and not request.dataset.is_dir():
            # A bag's split files have no single window to cut: full updates only.
            from sonarmap.pipeline.engine.config.load import load_config

            config = load_config(
                graph.config_stages, request.config_path, request.overrides, graph.extra_sections
            )
            self.preview = Preview(
                McapSnapshot(request.dataset, scratch / "preview.mcap"),
                config,
                scratch / "window.mcap",
            )
        self._last_growth = 0.0
        self._said_waiting = ""
        self._preview_problem = ""
        self._preview_t_ns = 0  # the log time the preview was last published at
        self._arrived_t: list[int] = []  # the newest log time after each growth ...
        self._arrived_wall: list[float] = []  # ... and when it was seen
        self.updates: list[Update] = []
        self.closed = False

    def follow(self, clock: Callable[[], float] = time.time) -> list[Update]:
        """Poll and map until the recording is closed or idle; the updates made.

        The full updates run in a background thread; the preview (when there is one) maps
        each new keyframe here meanwhile.

        Raises:
            SourceError: the file is not an MCAP file (or not there).
            ConfigError: the config is bad (found by the first update).
            KeyboardInterrupt: Ctrl-C (what was committed stays in the store).
        """
        with unsaid(self.snapshot.path):  # the updates' reader names their private copy
            return self._follow(clock)

    def _follow(self, clock: Callable[[], float]) -> list[Update]:
        mapped_size = 0
        last_start = -float("inf")
        self._last_growth = clock()
        worker: threading.Thread | None = None
        done: list[Update | BaseException] = []
        while True:
            if worker is not None and not worker.is_alive():
                worker.join()
                worker = None
                self._finished(done.pop())
            now = clock()
            if worker is None:
                growth = self.snapshot.update()
                self._note(growth, now)
                if growth.closed:
                    self.closed = True
                    return self.updates
                self._say_why_waiting(now)
                idle = self.options.idle_timeout_s
                if idle is not None and now - self._last_growth >= idle:
                    self._say(f"follow: no growth for {idle:g} s: mapping what was written")
                    return self.updates
                if self.snapshot.size > mapped_size and now - last_start >= self.options.every_s:
                    last_start, mapped_size = now, self.snapshot.size
                    worker = threading.Thread(
                        target=lambda: done.append(_caught(lambda: self._update(clock))),
                        name="sonarmap-follow-update",
                        daemon=True,  # Ctrl-C ends follow; the store's commits are atomic
                    )
                    worker.start()
            if not self._preview_step(clock):
                time.sleep(self.options.poll_s)

    def _say_why_waiting(self, now: float) -> None:
        """Once per reason: what a recording that stopped growing but is not closed waits
        for (a listed split file, or the file itself, without its footer)."""
        why = self.snapshot.waiting
        if why and why != self._said_waiting and now - self._last_growth >= WAITING_SAY_S:
            self._say(
                f"follow: {why}: waiting for it (a recorder that died leaves a file so:"
                " --idle-timeout-s maps what was written)"
            )
            self._said_waiting = why

    def _note(self, growth: Growth, now: float) -> None:
        if growth.new_bytes:
            self._last_growth = now
            if growth.last_log_time_ns is not None:
                self._arrived_t.append(growth.last_log_time_ns)
                self._arrived_wall.append(now)

    def _finished(self, outcome: Update | BaseException) -> None:
        """A full update ended: its line; its map supersedes the preview, which restarts
        from its newest keyframe."""
        if isinstance(outcome, BaseException):
            raise outcome
        self.updates.append(outcome)
        self._say(outcome.line())
        if self.preview is not None and outcome.anchor is not None:
            self.preview.set_anchor(outcome.anchor)
            self._publish_preview(outcome.t_last_ns)

    def _preview_step(self, clock: Callable[[], float]) -> bool:
        """Map the keyframes newly complete; whether any was."""
        if self.preview is None:
            return False
        try:
            new = self.preview.poll()
        except (PipelineError, ValueError) as err:
            self._note(self.preview.growth, clock())
            # The window is read as a recording of its own: what it lacks (no navigation
            # in it, a sonar silent for its seconds) stops the preview, never the updates.
            problem = str(err).replace(str(self.preview.window_path), "window")[:200]
            if problem != self._preview_problem:
                self._say(f"follow: no preview ({problem}); the full updates go on")
            self._preview_problem = problem
            return False
        self._preview_problem = ""
        self._note(self.preview.growth, clock())
        if not new:
            return False
        self._publish_preview(new[-1].t_ns)
        now = clock()
        for kf in new:
            arrival = self.arrival(kf.t_ns)
            lag = "" if arrival is None else f", lag {now - arrival:.1f} s"
            self._say(f"follow: preview keyframe {kf.keyframe_id}: {len(kf.xyz)} points{lag}")
        return True

    def clear_preview(self) -> None:
        """The final run's map is out: the preview is cleared from the live view."""
        if self.preview is not None:
            self.preview.keyframes = []
            self._publish_preview(None)

    def _publish_preview(self, t_ns: int | None) -> None:
        """Publish the preview at `t_ns`, or at the last time it was published when
        later (its log time never goes back: an update's newest keyframe is older than the
        preview's, and a clear has no time of its own)."""
        if self.preview is None or self._publish is None:
            return
        self._preview_t_ns = max(self._preview_t_ns, t_ns or 0)
        messages = self.preview.messages(self._preview_t_ns)
        self._publish(PREVIEW_TOPICS, lambda: messages)

    def _update(self, clock: Callable[[], float]) -> Update:
        names = [s.name for s in self.graph.stages]
        request = replace(
            self.request,
            dataset=self.snapshot.path,
            until=MAP_STAGE if MAP_STAGE in names else None,
            figures=False,
            force=(),
            # In this process: the imports, the model and the warm caches stay from one
            # update to the next (worker processes would start over each time: measured
            # 5 s an update with two of them at 1-4 keyframes, 2 s in-process).
            workers=1,
        )
        update = Update(len(self.updates) + 1, self.snapshot.size)
        start = clock()
        try:
            result, summary = run_dataset(request, self.graph, on_stage=self._on_stage)
        except ConfigError:
            raise
        except PipelineError as err:
            # A recording's first seconds often cannot be mapped yet (no navigation
            # under the pings, no keyframe, an empty map): the next update has more.
            update.problem = str(err).replace(str(self.snapshot.path), "snapshot")[:200]
            return update
        if self._drain is not None:
            self._drain()
        done = clock()
        update.compute_s = done - start
        update.keyframes = summary.get("keyframes")
        update.voxels = dict(summary.get("voxels") or {})
        update.warnings = len(result.warnings)
        update.t_last_ns = _t_last(result)
        arrival = self.arrival(update.t_last_ns)
        update.lag_s = None if arrival is None else done - arrival
        if self.preview is not None:
            update.anchor = anchor_of(result, {s.name: s for s in self.graph.stages})
        return update

    def arrival(self, t_ns: int | None) -> float | None:
        """When data at log time `t_ns` was first seen in the recording (None: unknown)."""
        if t_ns is None:
            return None
        i = bisect.bisect_left(self._arrived_t, t_ns)
        return self._arrived_wall[i] if i < len(self._arrived_wall) else None


def _caught(work: Callable[[], Update]) -> Update | BaseException:
    """`work()`, or what it raised (handed to the follow loop, which raises it)."""
    try:
        return work()
    except BaseException as err:  # the loop's thread raises it again
        return err


def _t_last(result: Any) -> int | None:
    """The newest keyframe's log time in a run's keyframes artifact."""
    ref = result.artifacts.get("keyframes")
    path = None if ref is None else Path(ref.path) / "keyframes.parquet"
    if path is None or not path.is_file():
        return None
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    t = pq.read_table(path, columns=["t_ns"]).column("t_ns")
    return None if len(t) == 0 else int(pc.max(t).as_py())
