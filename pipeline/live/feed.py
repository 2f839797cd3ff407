"""`on_stage` callback of the live view: each finished stage's artifacts become
Foxglove messages (`sonarmap.stages.evaluate.foxglove_scene`) on the live server.

keyframes: the fan images, the dead-reckoning (and true) trajectory and the scene mesh;
fuse: the fused points at dead-reckoning poses; classify: the objects; slam: /tf and
the trajectories (objects again, at SLAM poses); voxelize: the maps; evaluate: the
maps again with each point's error.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.pipeline.live.server import LiveServer
from sonarmap.stages.base import Stage
from sonarmap.stages.evaluate.foxglove_scene import SceneMessage

__all__ = ["LiveFeed"]


class LiveFeed:
    """Turns `StageResult`s (the runner's `on_stage`) into submissions to a LiveServer.

    Reads outputs from the finished artifacts' directories, and only when the server
    builds (a client is looking): `on_stage` itself records a path and returns.
    """

    def __init__(self, server: LiveServer, stages: Sequence[Stage]) -> None:
        self.server = server
        self._stages = {s.name: s for s in stages}
        self._dirs: dict[str, Path] = {}

    def on_stage(self, result: Any) -> None:
        """Runner callback (`sonarmap.pipeline.engine.run.runner.StageResult`): publish this stage."""
        self.add(result.stage, Path(result.path))

    def add(self, stage: str, directory: Path) -> None:
        """A finished (computed or cached) artifact of `stage` in `directory`."""
        self._dirs[stage] = directory
        job = _JOBS.get(stage)
        if job is not None:
            topics, build = job
            dirs = dict(self._dirs)  # what is known now: later stages do not leak in
            self.server.submit(topics, lambda: build(_Reader(self._stages, dirs)))


class _Reader:
    """Outputs of the finished artifacts by "stage.output" name (None when absent)."""

    def __init__(self, stages: dict[str, Stage], dirs: dict[str, Path]) -> None:
        self._stages, self._dirs = stages, dirs

    def __call__(self, name: str) -> Any:
        from sonarmap.pipeline.engine.store.codecs import read_output
        from sonarmap.pipeline.formats.frames_codec import FRAMES_CODECS

        stage, _, output = name.partition(".")
        if stage not in self._dirs or stage not in self._stages:
            return None
        spec = next((o for o in self._stages[stage].outputs if o.name == output), None)
        return None if spec is None else read_output(self._dirs[stage], spec, codecs=FRAMES_CODECS)

    def T_base_sonar(self) -> np.ndarray:
        from sonarmap.schemas.sensors import Sensors

        return Sensors.of(self("keyframes.sensors") or {}).horizontal.T_base_sonar

    def t_last(self) -> int:
        keyframes = self("keyframes.keyframes")
        return int(max(keyframes.column("t_ns").to_pylist(), default=0))


def _keyframes(read: _Reader) -> Iterator[SceneMessage]:
    from sonarmap.stages.evaluate.foxglove_images import fan_messages
    from sonarmap.stages.evaluate.foxglove_scene import mesh_messages, trajectory_messages
    from sonarmap.stages.kernels.ply import decode_mesh_ply

    keyframes = read("keyframes.keyframes")
    yield from trajectory_messages(keyframes, None)
    mesh = read("keyframes.scene_mesh")
    if mesh is not None:
        yield from mesh_messages(decode_mesh_ply(mesh), min(keyframes.column("t_ns").to_pylist()))
    yield from fan_messages(read("keyframes.frames"))


def _fuse(read: _Reader) -> list[SceneMessage]:
    from sonarmap.stages.evaluate.foxglove_scene import fused_messages

    return fused_messages(read("fuse.fused"), read("keyframes.keyframes"), read.T_base_sonar())


def _objects(read: _Reader) -> list[SceneMessage]:
    from sonarmap.stages.evaluate.foxglove_scene import object_messages

    poses = read("slam.poses") or read("keyframes.keyframes")
    return object_messages(read("classify.objects"), poses, read.T_base_sonar())


def _slam(read: _Reader) -> list[SceneMessage]:
    from sonarmap.stages.evaluate.foxglove_scene import trajectory_messages

    out = trajectory_messages(read("keyframes.keyframes"), read("slam.poses"))
    return out + (_objects(read) if read("classify.objects") is not None else [])


def _maps(read: _Reader) -> list[SceneMessage]:
    from sonarmap.stages.evaluate.foxglove_scene import map_messages

    return map_messages(read("voxelize.map"), read.t_last(), read("evaluate.errors"))


_TRAJECTORIES = (
    "/tf",
    "/trajectory/slam",
    "/trajectory/dead_reckoning",
    "/trajectory/ground_truth",
)
_MAPS = ("/map/standard", "/map/semantic")
_JOBS: dict[str, tuple[tuple[str, ...], Callable[[_Reader], Iterable[SceneMessage]]]] = {
    "keyframes": (
        ("/sonar/horizontal/fan", "/sonar/vertical/fan", "/ground_truth/mesh", *_TRAJECTORIES),
        _keyframes,
    ),
    "fuse": (("/live/fused",), _fuse),
    "classify": (("/objects",), _objects),
    "slam": ((*_TRAJECTORIES, "/objects"), _slam),
    "voxelize": (_MAPS, _maps),
    "evaluate": (_MAPS, _maps),
}
"""Per stage: the topics it publishes and how its messages are built."""
