"""Procedural harbours: random scenes, seeded, for training a classifier that generalises.

Hand-written training scenes teach the layouts someone thought of. `generate_scene` draws
a harbour from ranges instead (`ProceduralConfig`, every range in config): walls as
polylines with odd angles and curves, rows and grids of pilings and lone dolphins of
any yaw, trusses along and between rows, hulls of any size and heading, depths from
shallow to deep, and objects that touch and hide each other (a hull moored against a
wall, a truss braced on pilings, pilings in clusters). The missions through these worlds
are the simulator's own (`sonarmap.sim.mission`).

Every object's footprint lies inside the scene's working area, and every scene holds
every class, so a training set of a few worlds already covers the table. The free water
at the mission's depth and clearance is one piece (`sonarmap.sim.open_water`), so the mission
reaches every goal it draws.
"""

from __future__ import annotations

import math

from sonarmap.sim.procedural_config import ProceduralConfig
from sonarmap.sim.scene import (
    BoatHull,
    CylindricalPiling,
    PilingGrid,
    PilingRow,
    PilingSpec,
    RectangularPiling,
    Scene,
    Seawall,
    Truss,
)
from sonarmap.stages.kernels.lazy import lazy

np = lazy("numpy")  # loads when a scene is built or drawn, not when a config is read

__all__ = ["ProceduralConfig", "generate_scene", "scene_yaml"]

Span = tuple[float, float]
Count = tuple[int, int]


class _Draw:
    """The scene's random draws, in one order fixed by the code (deterministic by seed)."""

    def __init__(self, seed: int, half: float) -> None:
        self.rng = np.random.default_rng(seed)
        self.half = half

    def span(self, s: Span) -> float:
        return float(self.rng.uniform(s[0], s[1]))

    def count(self, c: Count) -> int:
        return int(self.rng.integers(c[0], c[1] + 1))

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def point(self, margin: float) -> np.ndarray:
        lim = max(self.half - margin, 0.5)
        return self.rng.uniform(-lim, lim, 2)

    def heading(self) -> float:
        return float(self.rng.uniform(-math.pi, math.pi))


def _inside(xy: np.ndarray, limit: float) -> np.ndarray:
    return np.clip(xy, -limit, limit)


def _to_edge(p: np.ndarray, heading: float, length: float, limit: float) -> tuple[np.ndarray, bool]:
    """The point `length` from p along heading, or where that line first meets the area's
    edge (and True): a wall that runs out of the area ends there, as quays run off a chart."""
    step = np.array([math.cos(heading), math.sin(heading)])
    room = [
        ((limit if step[a] > 0 else -limit) - p[a]) / step[a]
        for a in (0, 1)
        if abs(step[a]) > 1e-12
    ]
    t = min(length, *room)
    return p + max(t, 0.0) * step, t < length


def _wall_steps(
    d: _Draw, cfg: ProceduralConfig, heading: float, inwards: float
) -> list[tuple[float, float]]:
    """(heading [rad], length [m]) of a wall's straight pieces; an arc is 6 of them, and an
    arc that leaves the edge bends inwards (`inwards`: the sign of that turn), not out of
    the area at once."""
    steps: list[tuple[float, float]] = []
    for _ in range(d.count(cfg.wall_segments)):
        length = d.span(cfg.wall_segment_m)
        turn = math.radians(d.span(cfg.wall_turn_deg))
        if d.chance(cfg.wall_curve_share):
            turn = turn if steps else math.copysign(turn, inwards)
            for _ in range(6):
                heading += turn / 6
                steps.append((heading, length / 6))
        else:
            steps.append((heading, length))
            heading += turn
    return steps


def _wall(d: _Draw, cfg: ProceduralConfig, k: int) -> Seawall:
    """A polyline from the area's edge, turning at odd angles, some turns as arcs, ending
    where it meets the edge again.

    It leaves the edge tilted inwards. Clipping its points to the area instead laid 2/3 of
    the walls' length onto the edge, curves folded flat on it.
    """
    limit = d.half - 0.5
    side = d.rng.integers(4)
    along = d.span((-0.8, 0.8)) * limit
    start = np.array([[limit, along], [-limit, along], [along, limit], [along, -limit]][side])
    inwards = 1.0 if side < 2 else -1.0  # the turn that points the along-edge heading inside
    heading = [math.pi / 2, -math.pi / 2, 0.0, math.pi][side] + inwards * abs(d.span((-0.3, 0.3)))
    points = [start]
    for step_heading, length in _wall_steps(d, cfg, heading, inwards):
        end, at_edge = _to_edge(points[-1], step_heading, length, limit)
        points.append(end)
        if at_edge:
            break
    xy = np.array(points)
    keep = np.r_[True, np.linalg.norm(np.diff(xy, axis=0), axis=1) > 0.3]
    if keep.sum() < 2:  # pieces shorter than 0.3 m (a small `wall_segment_m`): its end
        keep[-1] = True
    xy = xy[keep]
    return Seawall(
        name=f"wall{k}",
        polyline_m=[(round(float(x), 3), round(float(y), 3)) for x, y in xy],
        corrugation_period_m=round(d.span(cfg.corrugation_period_m), 3),
        corrugation_depth_m=round(d.span(cfg.corrugation_depth_m), 3),
    )


def _piling(d: _Draw, cfg: ProceduralConfig, rectangular: bool | None = None) -> PilingSpec:
    if rectangular if rectangular is not None else d.chance(cfg.rectangular_share):
        side = d.span(cfg.square_side_m)
        aspect = d.span(cfg.rectangular_aspect)
        return PilingSpec(
            shape="rectangular",
            width_m=round(min(side * aspect, 1.2), 3),
            depth_m=round(side, 3),
            yaw_deg=round(d.span((0.0, 180.0)), 1),
        )
    return PilingSpec(shape="cylindrical", radius_m=round(d.span(cfg.round_radius_m), 3))


def _row(d: _Draw, cfg: ProceduralConfig, k: int, spec: PilingSpec) -> PilingRow:
    n = d.count(cfg.row_pilings)
    length = (n - 1) * d.span(cfg.row_spacing_m)
    start = d.point(1.5)
    heading = d.heading()
    end = _inside(start + length * np.array([math.cos(heading), math.sin(heading)]), d.half - 1.5)
    if np.linalg.norm(end - start) < 2.0:  # clipped short: run the other way
        end = _inside(
            start - length * np.array([math.cos(heading), math.sin(heading)]), d.half - 1.5
        )
    pts = [(round(float(v[0]), 3), round(float(v[1]), 3)) for v in (start, end)]
    return PilingRow(name=f"row{k}", start_m=pts[0], end_m=pts[1], count=n, piling=spec)


def _truss(d: _Draw, cfg: ProceduralConfig, a: np.ndarray, b: np.ndarray, name: str) -> Truss:
    top = d.span(cfg.truss_top_z_m)
    bays = max(1, round(float(np.linalg.norm(b - a)) / 2.5))
    return Truss(
        name=name,
        start_m=(round(float(a[0]), 3), round(float(a[1]), 3)),
        end_m=(round(float(b[0]), 3), round(float(b[1]), 3)),
        top_z_m=round(top, 3),
        bottom_z_m=round(top - d.span(cfg.truss_height_m), 3),
        bays=min(bays, 200),
    )


def _hull(d: _Draw, cfg: ProceduralConfig, k: int, walls: list[Seawall]) -> BoatHull:
    length = min(d.span(cfg.hull_length_m), 2 * d.half - 3.0)
    beam = length * d.span(cfg.hull_beam_share)
    if walls and d.chance(cfg.moored_share):
        # Moored: alongside a wall segment, touching it, heading along the wall.
        wall = walls[int(d.rng.integers(len(walls)))]
        xy = np.asarray(wall.polyline_m)
        i = int(d.rng.integers(len(xy) - 1))
        a, b = xy[i], xy[i + 1]
        t = d.span((0.2, 0.8))
        direction = (b - a) / np.linalg.norm(b - a)
        normal = np.array([-direction[1], direction[0]]) * (1 if d.chance(0.5) else -1)
        centre = a + t * (b - a) + normal * (beam / 2 + 0.05)
        yaw = math.degrees(math.atan2(direction[1], direction[0]))
    else:
        centre, yaw = d.point(length / 2 + 1.0), math.degrees(d.heading())
    centre = _inside(centre, d.half - length / 2 - 0.5)
    return BoatHull(
        name=f"hull{k}",
        position_m=(round(float(centre[0]), 3), round(float(centre[1]), 3)),
        yaw_deg=round(yaw, 1),
        length_m=round(length, 3),
        beam_m=round(beam, 3),
        draft_m=round(d.span(cfg.hull_draft_m), 3),
    )


def _dolphin(
    d: _Draw, cfg: ProceduralConfig, k: int
) -> list[CylindricalPiling | RectangularPiling]:
    """A lone cluster of 1-3 pilings, touching each other."""
    centre = d.point(2.0)
    spec = _piling(d, cfg)
    size = spec.radius_m * 2 if spec.shape == "cylindrical" else max(spec.width_m, spec.depth_m)
    out = []
    for i in range(d.count(cfg.dolphin_pilings)):
        offset = np.array([math.cos(2.1 * i), math.sin(2.1 * i)]) * size * (i > 0)
        xy = centre + offset
        out.append(spec.make((round(float(xy[0]), 3), round(float(xy[1]), 3)), f"dolphin{k}[{i}]"))
    return out


def _reach_m(obj: object) -> tuple[np.ndarray, float]:
    """Points of an object's plan footprint and how far its surface reaches past them."""
    if isinstance(obj, CylindricalPiling):
        return np.array([obj.position_m]), obj.radius_m
    if isinstance(obj, RectangularPiling):
        return np.array([obj.position_m]), math.hypot(obj.width_m, obj.depth_m) / 2
    if isinstance(obj, BoatHull):
        return np.array([obj.position_m]), obj.length_m / 2
    if isinstance(obj, Truss):
        return np.array([obj.start_m, obj.end_m]), obj.member_width_m
    assert isinstance(obj, Seawall)
    return np.array(obj.polyline_m), obj.corrugation_depth_m


def _within(obj: object, half: float) -> bool:
    points, reach = _reach_m(obj)
    return bool((np.abs(points) + reach <= half).all())


def _keep_inside(objects: list, half: float) -> list:
    """Objects whose footprint lies inside the area; a row or grid reaching out keeps the
    pilings that are inside."""
    out: list = []
    for obj in objects:
        if isinstance(obj, PilingRow | PilingGrid):
            pilings = obj.expand()
            if all(_within(p, half) for p in pilings):
                out.append(obj)
            else:
                out += [p for p in pilings if _within(p, half)]
        elif _within(obj, half):
            out.append(obj)
    return out


def generate_scene(config: ProceduralConfig, seed: int) -> Scene:
    """A random harbour holding every class, deterministic by `seed`, its free water one
    piece for the simulator's default mission (`sonarmap.sim.open_water.open_pockets`)."""
    half0 = _Draw(seed, 1.0).span(config.area_half_side_m)
    d = _Draw(seed, half0)
    d.span(config.area_half_side_m)  # keep the stream aligned with the draw above
    walls = [_wall(d, config, k) for k in range(d.count(config.walls))]
    objects: list = list(walls)
    rows = []
    n_rows = d.count(config.piling_rows)
    for k in range(n_rows):
        # The first row is round and the second square, so every scene holds both.
        spec = _piling(d, config, rectangular={0: False, 1: True}.get(k))
        rows.append(_row(d, config, k, spec))
    if n_rows == 1:
        objects.append(
            RectangularPiling(
                name="post", position_m=tuple(np.round(d.point(2.0), 3)), width_m=0.5, depth_m=0.5
            )
        )
    objects += rows
    trusses = [
        _truss(d, config, np.asarray(r.start_m), np.asarray(r.end_m), f"brace{k}")
        for k, r in enumerate(rows)
        if k == 0 or d.chance(config.truss_along_row_share)
    ]
    for k in range(min(d.count(config.trusses_between_rows), len(rows) - 1)):
        a, b = rows[k], rows[k + 1]
        trusses.append(_truss(d, config, np.asarray(a.end_m), np.asarray(b.start_m), f"span{k}"))
    objects += [t for t in trusses if np.hypot(*np.subtract(t.end_m, t.start_m)) > 1.0]
    for k in range(d.count(config.piling_grids)):
        spacing = d.span(config.grid_spacing_m)
        side = (d.count(config.grid_side), d.count(config.grid_side))
        extent = spacing * max(side)
        origin = d.point(extent * 1.5 + 1.0)
        objects.append(
            PilingGrid(
                name=f"grid{k}",
                origin_m=(round(float(origin[0]), 3), round(float(origin[1]), 3)),
                rows=side[0],
                cols=side[1],
                spacing_m=(round(spacing, 3), round(spacing * d.span((0.8, 1.2)), 3)),
                yaw_deg=round(math.degrees(d.heading()), 1),
                piling=_piling(d, config),
            )
        )
    for k in range(d.count(config.dolphins)):
        objects += _dolphin(d, config, k)
    objects += [_hull(d, config, k, walls) for k in range(d.count(config.hulls))]
    half = round(half0, 3)
    scene = Scene(
        name=f"procedural-{seed}",
        seafloor_depth_m=round(d.span(config.depth_m), 3),
        area_m=(-half, half, -half, half),
        seafloor_margin_m=35.0,
        objects=_keep_inside(objects, half),
    )
    if not config.open_water:
        return scene
    from sonarmap.sim.open_water import open_pockets  # scipy: only when a world is built

    return open_pockets(scene)


def scene_yaml(scene: Scene) -> str:
    """The scene as a YAML file `sonarmap.sim.scene.load_scene` reads back to an equal scene."""
    import yaml

    doc = scene.model_dump(mode="json", by_alias=True, exclude_none=True)
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
