"""Scene description (YAML) for the simulator: objects, their classes and geometry.

World frame: x east, y north, z up; z = 0 at the water surface, the seafloor is the
plane z = -seafloor_depth_m. Heights of pilings and walls are measured from the
seafloor; `None` means "up through the surface" (top at +1 m).

A scene YAML looks like::

    name: tiny
    seafloor_depth_m: 8.0
    area_m: [-15, 15, -15, 15]          # working area x_min, x_max, y_min, y_max
    objects:
      - {class: cylindrical_piling, position_m: [6, 0], radius_m: 0.25}
      - {class: piling_row, start_m: [0, 8], end_m: [10, 8], count: 4,
         piling: {shape: rectangular, width_m: 0.4, depth_m: 0.4}}

Helpers (`piling_row`, `piling_grid`) expand into individual pilings; every expanded
object gets an object id (0, 1, ... in file order) that the label images and the
ground-truth mesh carry. Structures of a site of your own come from mesh files, listed
after the objects (their ids follow them)::

    meshes:
      - {class: seawall, file: meshes/caisson.obj, position_m: [4, -6], yaw_deg: 30, scale: 1.0}
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sonarmap.stages.kernels.lazy import lazy

np = lazy("numpy")  # loads when a scene is built or drawn, not when a config is read

__all__ = [
    "BoatHull",
    "CylindricalPiling",
    "MeshObject",
    "PilingGrid",
    "PilingRow",
    "PilingSpec",
    "Primitive",
    "RectangularPiling",
    "Scene",
    "SceneError",
    "Seawall",
    "Truss",
    "load_scene",
    "meshes_found",
]

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class SceneError(ValueError):
    """A scene file cannot be read or is invalid (the message names the file and field)."""


class _Model(BaseModel):
    # allow_inf_nan: a NaN position passed the schema and wrote a recording whose ground
    # truth was corrupt (every number of a scene is a finite length or angle).
    model_config = ConfigDict(
        extra="forbid", frozen=True, populate_by_name=True, allow_inf_nan=False
    )


class CylindricalPiling(_Model):
    """Round vertical piling standing on the seafloor."""

    kind: Literal["cylindrical_piling"] = Field(default="cylindrical_piling", alias="class")
    name: str | None = None
    position_m: Vec2
    radius_m: float = Field(default=0.2, gt=0.0, le=5.0)
    height_m: float | None = Field(default=None, gt=0.0)


class RectangularPiling(_Model):
    """Square/rectangular vertical piling; `width_m` along x and `depth_m` along y before yaw."""

    kind: Literal["rectangular_piling"] = Field(default="rectangular_piling", alias="class")
    name: str | None = None
    position_m: Vec2
    width_m: float = Field(default=0.4, gt=0.0, le=10.0)
    depth_m: float = Field(default=0.4, gt=0.0, le=10.0)
    yaw_deg: float = 0.0
    height_m: float | None = Field(default=None, gt=0.0)


class Seawall(_Model):
    """Corrugated (sheet-pile) wall along a polyline, from the seafloor up."""

    kind: Literal["seawall"] = Field(default="seawall", alias="class")
    name: str | None = None
    polyline_m: list[Vec2] = Field(min_length=2)
    height_m: float | None = Field(default=None, gt=0.0)
    corrugation_period_m: float = Field(default=1.2, gt=0.0)
    corrugation_depth_m: float = Field(default=0.3, ge=0.0)

    @model_validator(mode="after")
    def _segments_nonzero(self) -> Seawall:
        p = np.asarray(self.polyline_m, dtype=float)
        if np.any(np.linalg.norm(np.diff(p, axis=0), axis=1) < 1e-6):
            raise ValueError("seawall polyline_m has a zero-length segment")
        return self


class BoatHull(_Model):
    """Floating hull: a half ellipsoid of the given draft plus freeboard, at the surface."""

    kind: Literal["boat_hull"] = Field(default="boat_hull", alias="class")
    name: str | None = None
    position_m: Vec2
    yaw_deg: float = 0.0
    length_m: float = Field(default=8.0, gt=0.0)
    beam_m: float = Field(default=3.0, gt=0.0)
    draft_m: float = Field(default=1.2, gt=0.0)
    freeboard_m: float = Field(default=0.8, ge=0.0)


class Truss(_Model):
    """Planar Warren truss between two plan points: chords at top/bottom z plus diagonals."""

    kind: Literal["truss"] = Field(default="truss", alias="class")
    name: str | None = None
    start_m: Vec2
    end_m: Vec2
    top_z_m: float = -0.5
    bottom_z_m: float = -1.5
    member_width_m: float = Field(default=0.15, gt=0.0)
    bays: int = Field(default=4, ge=1, le=200)

    @model_validator(mode="after")
    def _check(self) -> Truss:
        if self.top_z_m <= self.bottom_z_m:
            raise ValueError("truss top_z_m must be above bottom_z_m")
        if np.hypot(self.end_m[0] - self.start_m[0], self.end_m[1] - self.start_m[1]) < 1e-6:
            raise ValueError("truss start_m and end_m coincide")
        return self


class PilingSpec(_Model):
    """Shape of the pilings a row/grid helper creates."""

    shape: Literal["cylindrical", "rectangular"] = "cylindrical"
    radius_m: float = Field(default=0.2, gt=0.0, le=5.0)
    width_m: float = Field(default=0.4, gt=0.0, le=10.0)
    depth_m: float = Field(default=0.4, gt=0.0, le=10.0)
    yaw_deg: float = 0.0
    height_m: float | None = Field(default=None, gt=0.0)

    def make(self, xy: Vec2, name: str | None) -> CylindricalPiling | RectangularPiling:
        """One piling of this shape at `xy`."""
        if self.shape == "cylindrical":
            return CylindricalPiling(
                name=name, position_m=xy, radius_m=self.radius_m, height_m=self.height_m
            )
        return RectangularPiling(
            name=name,
            position_m=xy,
            width_m=self.width_m,
            depth_m=self.depth_m,
            yaw_deg=self.yaw_deg,
            height_m=self.height_m,
        )


class PilingRow(_Model):
    """`count` pilings evenly spaced from `start_m` to `end_m` (inclusive)."""

    kind: Literal["piling_row"] = Field(default="piling_row", alias="class")
    name: str | None = None
    start_m: Vec2
    end_m: Vec2
    count: int = Field(ge=2, le=1000)
    piling: PilingSpec = PilingSpec()

    def expand(self) -> list[CylindricalPiling | RectangularPiling]:
        s = np.linspace(0.0, 1.0, self.count)
        a, b = np.asarray(self.start_m), np.asarray(self.end_m)
        pts = a[None] + s[:, None] * (b - a)[None]
        base = self.name or "row"
        return [
            self.piling.make((float(p[0]), float(p[1])), f"{base}[{i}]") for i, p in enumerate(pts)
        ]


class PilingGrid(_Model):
    """rows x cols pilings from `origin_m`, spacing (dx, dy) rotated by `yaw_deg`."""

    kind: Literal["piling_grid"] = Field(default="piling_grid", alias="class")
    name: str | None = None
    origin_m: Vec2
    rows: int = Field(ge=1, le=200)
    cols: int = Field(ge=1, le=200)
    spacing_m: Vec2
    yaw_deg: float = 0.0
    piling: PilingSpec = PilingSpec()

    def expand(self) -> list[CylindricalPiling | RectangularPiling]:
        c, s = np.cos(np.deg2rad(self.yaw_deg)), np.sin(np.deg2rad(self.yaw_deg))
        out: list[CylindricalPiling | RectangularPiling] = []
        base = self.name or "grid"
        for i in range(self.rows):
            for j in range(self.cols):
                lx, ly = j * self.spacing_m[0], i * self.spacing_m[1]
                xy = (self.origin_m[0] + c * lx - s * ly, self.origin_m[1] + s * lx + c * ly)
                out.append(self.piling.make(xy, f"{base}[{i},{j}]"))
        return out


class MeshObject(_Model):
    """A triangle mesh from a file (OBJ, PLY, STL, read with open3d), of any class of the
    class table, scaled, turned by `yaw_deg` about z and moved to `position_m`; standing on
    the seafloor unless `z_m` puts its lowest point elsewhere."""

    class_name: str = Field(alias="class", min_length=1, max_length=64)
    name: str | None = None
    file: str = Field(min_length=1, max_length=4096, description="relative to the scene file")
    position_m: Vec2
    z_m: float | None = Field(default=None, description="height of its lowest point [m]")
    yaw_deg: float = Field(default=0.0, ge=-360.0, le=360.0)
    scale: float = Field(default=1.0, gt=0.0, le=1000.0)

    @property
    def kind(self) -> str:
        return self.class_name


Primitive = CylindricalPiling | RectangularPiling | Seawall | BoatHull | Truss | MeshObject
SceneObject = Annotated[
    CylindricalPiling | RectangularPiling | Seawall | BoatHull | Truss | PilingRow | PilingGrid,
    Field(discriminator="kind"),
]


MAX_AREA_SIDE_M = 10_000.0
"""Largest side of a scene's working area (the seafloor grid is 10 m cells over it)."""
MAX_COORD_M = 1e6
"""Farthest corner of the working area from the scene's origin."""
MAX_MARGIN_M = 1_000.0
"""Longest extension of the seafloor past the working area."""


class Scene(_Model):
    """A validated scene: seafloor depth, working area and objects (world frame, metres)."""

    name: str = "scene"
    seafloor_depth_m: float = Field(default=8.0, gt=0.5, le=200.0)
    area_m: tuple[float, float, float, float] = Field(
        description="working area (x_min, x_max, y_min, y_max) [m]; missions stay inside"
    )
    seafloor_margin_m: float = Field(
        default=40.0, ge=0.0, le=MAX_MARGIN_M, description="seafloor extends past the area"
    )
    objects: list[SceneObject] = Field(default_factory=list)
    meshes: list[MeshObject] = Field(
        default_factory=list, description="objects from mesh files, after `objects`"
    )

    @model_validator(mode="after")
    def _check_area(self) -> Scene:
        x0, x1, y0, y1 = self.area_m
        if x1 - x0 < 2.0 or y1 - y0 < 2.0:
            raise ValueError("area_m must be (x_min, x_max, y_min, y_max) with extent >= 2 m")
        if max(x1 - x0, y1 - y0) > MAX_AREA_SIDE_M or max(map(abs, self.area_m)) > MAX_COORD_M:
            # The seafloor is a grid over the area and its margin: bounded memory.
            raise ValueError(
                f"area_m must span at most {MAX_AREA_SIDE_M:g} m a side, within"
                f" {MAX_COORD_M:g} m of the origin (a harbour, not an ocean)"
            )
        return self

    def primitives(self) -> list[Primitive]:
        """Objects with helpers expanded, in file order (index = object id)."""
        out: list[Primitive] = []
        for obj in self.objects:
            if isinstance(obj, PilingRow | PilingGrid):
                out.extend(obj.expand())
            else:
                out.append(obj)
        return [*out, *self.meshes]


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene YAML.

    Raises:
        SceneError: unreadable file, bad YAML, or a validation error (naming the field).
    """
    import yaml  # here: validating the training section reads no scene

    p = Path(path)
    try:
        raw = yaml.safe_load(p.read_text())
    except OSError as err:
        raise SceneError(f"cannot read scene {p}: {err}") from err
    except yaml.YAMLError as err:
        raise SceneError(f"scene {p} is not valid YAML: {err}") from err
    if not isinstance(raw, dict):
        raise SceneError(f"scene {p} must be a YAML mapping, got {type(raw).__name__}")
    try:
        scene = Scene.model_validate(raw)
    except ValidationError as err:
        lines = [f"  {'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in err.errors()]
        raise SceneError(f"invalid scene {p}:\n" + "\n".join(lines)) from err
    return meshes_found(scene, p)


def meshes_found(scene: Scene, path: Path) -> Scene:
    """The scene with each mesh file's path made absolute (relative to the scene file)."""
    if not scene.meshes:
        return scene
    meshes = []
    for i, m in enumerate(scene.meshes):
        file = (path.parent / m.file).resolve()
        if not file.exists():
            raise SceneError(f"scene {path}: meshes[{i}].file: no such file {file}")
        if not file.is_file():  # a device or a FIFO would never end, a folder is no mesh
            raise SceneError(f"scene {path}: meshes[{i}].file: {file} is not a regular file")
        meshes.append(m.model_copy(update={"file": str(file)}))
    return scene.model_copy(update={"meshes": meshes})
