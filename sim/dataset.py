"""`simulate(scene, config, seed)`: a lazily generated, deterministic simulated mission."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import SonarPing
from sonarmap.sim.config import SimConfig
from sonarmap.sim.mission import Trajectory, dead_reckoning, plan_mission
from sonarmap.sim.scene import Scene
from sonarmap.sim.sonar import SonarModel
from sonarmap.sim.version import SIM_VERSION
from sonarmap.sim.world import World
from sonarmap.stages.kernels.geometry import matrix_from_rpy_product, se3

__all__ = ["SIM_VERSION", "SimFrame", "SimRun", "simulate"]


_MISSION_STREAM = 1
_NAV_STREAM = 2
_FRAME_STREAM = 3


@dataclass(frozen=True)
class SimFrame:
    """One ping pair.

    Attributes:
        index: frame number (0..n_frames-1).
        t_ns: ping time [ns].
        gt_pose: (6,) true base_link pose in odom (x, y, z [m], roll, pitch, yaw [rad]).
        dr_pose: (6,) dead-reckoned base_link pose in odom.
        horizontal, vertical: the pings, with labels and truth_angle_rad.
        T_base_sonar: {"horizontal": (4, 4), "vertical": (4, 4)} mountings.
    """

    index: int
    t_ns: int
    gt_pose: np.ndarray
    dr_pose: np.ndarray
    horizontal: SonarPing
    vertical: SonarPing
    T_base_sonar: dict[str, np.ndarray] = field(repr=False)


@dataclass
class SimRun:
    """A simulated mission: world, config, seed, trajectory; frames generated on demand.

    `trajectory` holds t_ns (n,) int64, gt_pose (n, 6), dr_pose (n, 6) at the ping times.
    """

    world: World
    config: SimConfig
    seed: int
    trajectory: dict[str, np.ndarray]
    path: Trajectory
    _models: dict[str, SonarModel] = field(default_factory=dict, init=False, repr=False)

    @property
    def n_frames(self) -> int:
        return len(self.trajectory["t_ns"])

    @property
    def T_base_sonar(self) -> dict[str, np.ndarray]:
        """Mountings {"horizontal", "vertical"} -> (4, 4) T_base_sonar."""
        return {s: self.config.sonar(s).mounting.matrix() for s in ("horizontal", "vertical")}

    def frame(self, index: int) -> SimFrame:
        """Frame `index`, identical whenever it is generated (per-frame seeded RNG)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} outside 0..{self.n_frames - 1}")
        models = self.sonar_models()
        mounts = self.T_base_sonar
        gt = self.trajectory["gt_pose"][index]
        t_ns = int(self.trajectory["t_ns"][index])
        T_world_base = se3(matrix_from_rpy_product(gt[3:6]), gt[:3])
        rng = np.random.default_rng([self.seed, _FRAME_STREAM, index])
        pings = {
            s: models[s].render(self.world, T_world_base @ mounts[s], rng, t_ns)
            for s in ("horizontal", "vertical")
        }
        return SimFrame(
            index=index,
            t_ns=t_ns,
            gt_pose=gt.copy(),
            dr_pose=self.trajectory["dr_pose"][index].copy(),
            horizontal=pings["horizontal"],
            vertical=pings["vertical"],
            T_base_sonar=mounts,
        )

    def frames(self) -> Iterator[SimFrame]:
        """All frames in time order, generated lazily."""
        for i in range(self.n_frames):
            yield self.frame(i)

    def sonar_models(self) -> dict[str, SonarModel]:
        """The two sonar image models (built once)."""
        if not self._models:
            for s in ("horizontal", "vertical"):
                self._models[s] = SonarModel(self.config.sonar(s), s, self.world.table)
        return self._models


def simulate(
    scene: Scene, config: SimConfig, seed: int, table: ClassTable = DEFAULT_TABLE
) -> SimRun:
    """Plan the mission and navigation for (scene, config, seed); pings render lazily.
    `table`: the class table (label ids of the scene's classes).

    Raises:
        ValueError: no free water for the mission.
    """
    world = World(scene, table=table)
    mission_rng = np.random.default_rng([seed, _MISSION_STREAM])
    path = plan_mission(world, config.mission, config.navigation.rate_hz, mission_rng)
    dr_nav = dead_reckoning(path, config.navigation, np.random.default_rng([seed, _NAV_STREAM]))
    dt_ns = round(1e9 / config.ping_rate_hz)
    n = int(np.floor(path.duration_s * 1e9 / dt_ns)) + 1
    rel_ns = np.arange(n, dtype=np.int64) * dt_ns
    t_s = rel_ns / 1e9
    gt = path.sample(t_s)
    dr = np.stack(
        [np.interp(t_s, path.t_s, dr_nav[:, i]) for i in range(5)]
        + [np.interp(t_s, path.t_s, np.unwrap(dr_nav[:, 5]))],
        axis=1,
    )
    dr[:, 5] = (dr[:, 5] + np.pi) % (2 * np.pi) - np.pi
    traj = {"t_ns": rel_ns + config.start_time_ns, "gt_pose": gt, "dr_pose": dr}
    return SimRun(world=world, config=config, seed=seed, trajectory=traj, path=path)
