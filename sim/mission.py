"""Vehicle mission (paper Sec. V.B protocol) and dead-reckoning navigation.

Random start and goals in free water (clearance from every object at vehicle depth),
visited in nearest-neighbour order along A* paths on a 2D occupancy grid (8-connected,
then shortcut by line of sight), at constant speed and depth. Heading follows the
path (turning in place at a fixed yaw rate) or is held constant (strafing).
"""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass

import numpy as np

from sonarmap.sim.config import MissionConfig, NavigationNoise
from sonarmap.sim.world import World

log = logging.getLogger(__name__)

__all__ = ["Occupancy", "Trajectory", "dead_reckoning", "plan_mission"]


@dataclass(frozen=True)
class Occupancy:
    """Free-water grid at vehicle depth: free[i, j] for cell centre (xs[i], ys[j])."""

    xs: np.ndarray
    ys: np.ndarray
    free: np.ndarray

    @classmethod
    def build(cls, world: World, mission: MissionConfig) -> Occupancy:
        x0, x1, y0, y1 = world.scene.area_m
        res = mission.grid_resolution_m
        xs = np.arange(x0 + res / 2, x1, res)
        ys = np.arange(y0 + res / 2, y1, res)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -mission.depth_m)], axis=1)
        dist = world.distance(pts, include_seafloor=False).reshape(gx.shape)
        return cls(xs, ys, dist > mission.clearance_m + res / 2)

    def cell(self, xy: np.ndarray) -> tuple[int, int]:
        res = self.xs[1] - self.xs[0] if len(self.xs) > 1 else 1.0
        i = int(np.clip(np.rint((xy[0] - self.xs[0]) / res), 0, len(self.xs) - 1))
        j = int(np.clip(np.rint((xy[1] - self.ys[0]) / res), 0, len(self.ys) - 1))
        return i, j

    def line_free(self, a: tuple[int, int], b: tuple[int, int]) -> bool:
        n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1])) * 2) + 2
        ii = np.rint(np.linspace(a[0], b[0], n)).astype(int)
        jj = np.rint(np.linspace(a[1], b[1], n)).astype(int)
        return bool(self.free[ii, jj].all())


def _astar(
    occ: Occupancy, start: tuple[int, int], goal: tuple[int, int]
) -> list[tuple[int, int]] | None:
    """8-connected A* on `occ.free` (graph search over cells); None if unreachable."""
    nx, ny = occ.free.shape
    steps = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]
    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(0.0, start)]
    closed: set[tuple[int, int]] = set()
    while heap:
        _, cur = heapq.heappop(heap)
        if cur == goal:
            path = [cur]
            while cur in parent:
                cur = parent[cur]
                path.append(cur)
            return path[::-1]
        if cur in closed:
            continue
        closed.add(cur)
        for di, dj in steps:
            nb = (cur[0] + di, cur[1] + dj)
            if not (0 <= nb[0] < nx and 0 <= nb[1] < ny) or not occ.free[nb]:
                continue
            ng = g[cur] + (1.4142135623730951 if di and dj else 1.0)
            if ng < g.get(nb, np.inf):
                g[nb] = ng
                parent[nb] = cur
                h = float(np.hypot(goal[0] - nb[0], goal[1] - nb[1]))
                heapq.heappush(heap, (ng + h, nb))
    return None


def _shortcut(occ: Occupancy, path: list[tuple[int, int]]) -> list[tuple[int, int]]:
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and not occ.line_free(path[i], path[j]):
            j -= 1
        out.append(path[j])
        i = j
    return out


@dataclass(frozen=True)
class Trajectory:
    """Ground-truth planar trajectory sampled at the navigation rate.

    t_s (n,) [s from start]; xy (n, 2) [m]; yaw (n,) [rad, unwrapped]; z_m constant;
    waypoints (m, 2) the planned path corners; goals (g, 2).
    """

    t_s: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    z_m: float
    waypoints: np.ndarray
    goals: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    def sample(self, t_s: np.ndarray) -> np.ndarray:
        """(len(t_s), 6) poses (x, y, z, 0, 0, yaw) interpolated at times t_s."""
        x = np.interp(t_s, self.t_s, self.xy[:, 0])
        y = np.interp(t_s, self.t_s, self.xy[:, 1])
        yaw = np.interp(t_s, self.t_s, self.yaw)
        z = np.full_like(x, self.z_m)
        return np.stack([x, y, z, np.zeros_like(x), np.zeros_like(x), _wrap(yaw)], axis=1)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def plan_mission(
    world: World, mission: MissionConfig, rate_hz: float, rng: np.random.Generator
) -> Trajectory:
    """Random start, `n_goals` random free goals, nearest-neighbour order, A* paths, timing.

    Raises:
        ValueError: the scene has no free water at the mission depth, or no goal can be
            reached from the start (a pocket of water closed in by obstacles).
    """
    occ = Occupancy.build(world, mission)
    free = np.argwhere(occ.free)
    if len(free) < 2:
        raise ValueError("scene has no free water at the mission depth/clearance")
    cells = free[rng.permutation(len(free))]
    start = (int(cells[0][0]), int(cells[0][1]))
    pts = np.stack([occ.xs[cells[:, 0]], occ.ys[cells[:, 1]]], axis=1)
    goals: list[int] = []
    for idx in range(1, len(cells)):
        if len(goals) >= mission.n_goals:
            break
        chosen = [0, *goals]
        if np.min(np.linalg.norm(pts[chosen] - pts[idx], axis=1)) >= mission.min_goal_separation_m:
            goals.append(idx)
    # Nearest-neighbour order along reachable A* paths.
    corners = [start]
    cur, remaining, visited = start, list(goals), []
    while remaining:
        d = [np.hypot(cells[g][0] - cur[0], cells[g][1] - cur[1]) for g in remaining]
        g = remaining.pop(int(np.argmin(d)))
        tgt = (int(cells[g][0]), int(cells[g][1]))
        path = _astar(occ, cur, tgt)
        if path is None or len(path) < 2:
            continue
        corners.extend(_shortcut(occ, path)[1:])
        visited.append(tgt)
        cur = tgt
    if not visited:
        raise ValueError(
            "no goal can be reached from the mission's start (a pocket of free water closed"
            " in by obstacles at mission.depth_m / mission.clearance_m): try another seed"
        )
    if len(visited) < mission.n_goals:  # never silent: the mission is shorter than asked
        log.warning(
            "mission: %d of the %d goals asked for are reachable from the start (obstacles"
            " at mission.depth_m / mission.clearance_m, or too little water for"
            " mission.min_goal_separation_m)", len(visited), mission.n_goals,
        )  # fmt: skip
    wp = np.array([[occ.xs[i], occ.ys[j]] for i, j in corners])
    goal_xy = np.array([[occ.xs[i], occ.ys[j]] for i, j in visited]).reshape(-1, 2)
    t_k, xy_k, yaw_k = _timing(wp, mission, rng)
    t = np.arange(0.0, t_k[-1] + 1e-9, 1.0 / rate_hz)
    if mission.duration_s is not None:
        t = t[t <= mission.duration_s]
    xy = np.stack([np.interp(t, t_k, xy_k[:, 0]), np.interp(t, t_k, xy_k[:, 1])], axis=1)
    return Trajectory(t, xy, np.interp(t, t_k, yaw_k), -mission.depth_m, wp, goal_xy)


def _timing(
    wp: np.ndarray, mission: MissionConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Knots (t, xy, unwrapped yaw): turn in place, then translate at constant speed."""
    seg = np.diff(wp, axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0]) if len(seg) else np.zeros(0)
    yaw0 = heading[0] if len(heading) else 0.0
    if mission.heading_mode == "constant":
        yaw0 = float(rng.uniform(-np.pi, np.pi))
    t, xy, yaw = [0.0], [wp[0]], [float(yaw0)]
    rate = np.deg2rad(mission.yaw_rate_deg_s)
    for k in range(len(seg)):
        if mission.heading_mode == "path":
            dyaw = float(_wrap(np.array(heading[k] - yaw[-1])))
            if abs(dyaw) > 1e-9:
                t.append(t[-1] + abs(dyaw) / rate)
                xy.append(xy[-1])
                yaw.append(yaw[-1] + dyaw)
        t.append(t[-1] + float(np.linalg.norm(seg[k])) / mission.speed_m_s)
        xy.append(wp[k + 1])
        yaw.append(yaw[-1])
    if len(t) == 1:
        t.append(1.0)
        xy.append(wp[0])
        yaw.append(yaw[0])
    return np.asarray(t), np.asarray(xy), np.asarray(yaw)


def dead_reckoning(
    traj: Trajectory, noise: NavigationNoise, rng: np.random.Generator
) -> np.ndarray:
    """Dead-reckoned poses (n, 6) from a noisy DVL body velocity, biased IMU yaw, depth sensor.

    Integrates p[k+1] = p[k] + R(yaw_meas[k]) v_meas[k] dt, starting at the true pose.
    """
    n = len(traj.t_s)
    dt = np.diff(traj.t_s)
    yaw = traj.yaw
    v_w = np.zeros((n, 2))
    if n > 1:
        v_w[:-1] = np.diff(traj.xy, axis=0) / dt[:, None]
    c, s = np.cos(yaw), np.sin(yaw)
    v_b = np.stack([c * v_w[:, 0] + s * v_w[:, 1], -s * v_w[:, 0] + c * v_w[:, 1]], axis=1)
    scale = 1.0 + rng.normal(0.0, noise.dvl_scale_error, 2)
    v_m = v_b * scale[None] + rng.normal(0.0, noise.dvl_noise_m_s, (n, 2))
    bias0 = np.deg2rad(rng.normal(0.0, noise.yaw_bias_deg))
    walk = np.deg2rad(noise.yaw_bias_walk_deg_sqrt_s) * np.sqrt(np.r_[0.0, dt])
    bias = bias0 + np.cumsum(rng.normal(0.0, 1.0, n) * walk)
    yaw_m = yaw + bias + np.deg2rad(rng.normal(0.0, noise.yaw_noise_deg, n))
    cm, sm = np.cos(yaw_m), np.sin(yaw_m)
    step = np.stack([cm * v_m[:, 0] - sm * v_m[:, 1], sm * v_m[:, 0] + cm * v_m[:, 1]], axis=1)
    xy = np.empty((n, 2))
    xy[0] = traj.xy[0]
    if n > 1:
        xy[1:] = traj.xy[0] + np.cumsum(step[:-1] * dt[:, None], axis=0)
    z = traj.z_m + rng.normal(0.0, noise.depth_noise_m, n)
    return np.stack([xy[:, 0], xy[:, 1], z, np.zeros(n), np.zeros(n), _wrap(yaw_m)], axis=1)
