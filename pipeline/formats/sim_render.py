"""Frames of a simulated run rendered ahead of the MCAP writer in worker processes.

Each frame depends only on (scene, config, seed, its index) (`SimRun.frame` seeds its RNG
per index), so frames rendered in any process, in any order, are the frames a serial run
renders; they are yielded in index order, so the file's bytes do not depend on the
number of workers (`sonarmap.stages.kernels.parallel.ordered_map`, spawned processes: image formation is
numpy code that holds the GIL between its calls). A worker costs
about a second to start (importing open3d), and on a loaded machine the processes
compete for the same cores (see benchmarks/bench_simulate.py), so one worker (serial, in
this process) stays the default.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from sonarmap.schemas.sonar import SonarPing
from sonarmap.sim.dataset import SimFrame, SimRun
from sonarmap.sim.world import World
from sonarmap.stages.kernels.parallel import ordered_map

__all__ = ["rendered_frames"]

_RUN: SimRun | None = None
"""The worker process's copy of the run (set once by `_start_worker`)."""


def _start_worker(state: dict[str, Any], cast_threads: int) -> None:
    global _RUN
    world = World(state.pop("scene"), cast_threads=cast_threads, table=state.pop("table"))
    _RUN = SimRun(world=world, **state)


_NAN_BITS = np.array(np.nan, np.float32).view(np.uint32)
"""The fill of a ping's truth-angle image where no return is visible (`np.full(..., nan)`)."""

_Sparse = tuple[np.ndarray, np.ndarray]


def _render(index: int) -> tuple[SimFrame, dict[str, tuple[_Sparse, _Sparse]]]:
    """Frame `index`, its label and truth-angle images sent as (flat index, value) pairs.

    Those images are mostly empty (2.4 of a frame pair's 3.7 MB are NaN truth angles):
    sent sparse, a frame crosses the process boundary at a fifth of its size.
    """
    assert _RUN is not None, "worker not initialised"
    frame = _RUN.frame(index)
    sparse = {}
    pings: dict[str, SonarPing] = {}
    for name in ("horizontal", "vertical"):
        ping: SonarPing = getattr(frame, name)
        assert ping.labels is not None and ping.truth_angle_rad is not None
        labels, truth = ping.labels.ravel(), ping.truth_angle_rad.ravel()
        lab_idx = np.flatnonzero(labels)
        truth_idx = np.flatnonzero(truth.view(np.uint32) != _NAN_BITS)
        sparse[name] = ((lab_idx, labels[lab_idx]), (truth_idx, truth[truth_idx]))
        pings[name] = replace(ping, labels=None, truth_angle_rad=None)
    return replace(frame, horizontal=pings["horizontal"], vertical=pings["vertical"]), sparse


def _dense(frame: SimFrame, sparse: dict[str, tuple[_Sparse, _Sparse]]) -> SimFrame:
    """Inverse of `_render`'s packing: the frame exactly as `SimRun.frame` returned it."""
    pings: dict[str, SonarPing] = {}
    for name, ((lab_idx, lab), (truth_idx, truth)) in sparse.items():
        ping: SonarPing = getattr(frame, name)
        labels = np.zeros(ping.image.size, np.uint8)
        labels[lab_idx] = lab
        angles = np.full(ping.image.size, np.nan, np.float32)
        angles[truth_idx] = truth
        shape = ping.image.shape
        pings[name] = replace(
            ping, labels=labels.reshape(shape), truth_angle_rad=angles.reshape(shape)
        )
    return replace(frame, horizontal=pings["horizontal"], vertical=pings["vertical"])


def rendered_frames(run: SimRun, workers: int) -> Iterator[SimFrame]:
    """`run.frames()` in order; with `workers` > 1 rendered in that many processes.

    Each worker rebuilds the world from the scene (open3d scenes do not pickle) and casts
    on one thread, so the workers do not oversubscribe the cores between them.
    """
    if workers <= 1 or run.n_frames <= 1:
        yield from run.frames()
        return
    state = {
        "scene": run.world.scene,
        "table": run.world.table,
        "config": run.config,
        "seed": run.seed,
        "trajectory": run.trajectory,
        "path": run.path,
    }
    # A writer that stops early (an error, a full disk) waits for no further frames.
    for packed in ordered_map(_render, range(run.n_frames), workers, _start_worker, (state, 1)):
        yield _dense(*packed)
