"""Simulator objects from mesh files (issue 38, item 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.schemas.classes import CLASS_IDS
from sonarmap.sim.scene import SceneError, load_scene
from sonarmap.sim.world import World

# A 2 m x 1 m x 3 m block, its own origin at one corner (not its centre, nor its base).
CUBE_OBJ = """\
v 0 0 0
v 2 0 0
v 2 1 0
v 0 1 0
v 0 0 3
v 2 0 3
v 2 1 3
v 0 1 3
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""


def _scene(tmp_path: Path, mesh_line: str) -> Path:
    (tmp_path / "meshes").mkdir(exist_ok=True)
    (tmp_path / "meshes" / "block.obj").write_text(CUBE_OBJ)
    path = tmp_path / "site.yaml"
    path.write_text(
        "name: site\nseafloor_depth_m: 6.0\narea_m: [-10, 10, -10, 10]\n"
        "objects:\n  - {class: cylindrical_piling, position_m: [-5, -5], radius_m: 0.3}\n"
        f"meshes:\n  - {mesh_line}\n"
    )
    return path


def test_a_mesh_object_is_placed_scaled_turned_and_classed(tmp_path: Path) -> None:
    line = "{class: rectangular_piling, name: block, file: meshes/block.obj, position_m: [4, 2], yaw_deg: 90, scale: 0.5}"
    world = World(load_scene(_scene(tmp_path, line)))
    block = world.objects[1]
    assert (block.object_id, block.name, block.class_id) == (
        1,
        "block",
        CLASS_IDS["rectangular_piling"],
    )
    # Scaled to 1 x 0.5 x 1.5 m, turned 90 degrees (x -> y), origin corner at (4, 2), on the seafloor.
    assert np.allclose(block.bbox_min, (3.5, 2.0, -6.0)) and np.allclose(
        block.bbox_max, (4.0, 3.0, -4.5)
    )
    hit = world.cast(np.array([[0.0, 2.5, -5.0]]), np.array([[1.0, 0.0, 0.0]]))
    assert hit["object_id"][0] == 1 and np.isclose(hit["t_hit"][0], 3.5)
    assert hit["class_id"][0] == CLASS_IDS["rectangular_piling"]


def test_a_mesh_can_float_above_the_seafloor(tmp_path: Path) -> None:
    line = "{class: boat_hull, file: meshes/block.obj, position_m: [0, 0], z_m: -2.0}"
    world = World(load_scene(_scene(tmp_path, line)))
    assert np.isclose(world.objects[1].bbox_min[2], -2.0) and world.objects[1].name == "boat_hull_1"


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (
            "{class: seawall, file: meshes/nothing.obj, position_m: [0, 0]}",
            "meshes[0].file: no such file",
        ),
        (
            "{class: mooring_rock, file: meshes/block.obj, position_m: [0, 0]}",
            "not in the class table",
        ),
        ("{class: seawall, file: meshes/block.obj, position_m: [0, 0], scale: -1}", "scale"),
        (  # a device: it exists (it used to be called missing) and would never end
            "{class: seawall, file: /dev/zero, position_m: [0, 0]}",
            "meshes[0].file: /dev/zero is not a regular file",
        ),
    ],
)
def test_a_missing_file_an_unknown_class_or_a_bad_scale_is_refused(
    tmp_path: Path, line: str, message: str
) -> None:
    with pytest.raises(SceneError, match=message.replace("[", r"\[").replace("]", r"\]")):
        World(load_scene(_scene(tmp_path, line)))


def test_a_file_that_is_no_mesh_is_refused_naming_it(tmp_path: Path) -> None:
    path = _scene(tmp_path, "{class: seawall, file: meshes/block.obj, position_m: [0, 0]}")
    (tmp_path / "meshes" / "block.obj").write_text("this is not a mesh\n")
    with pytest.raises(SceneError, match=r"block\.obj: no triangles"):
        World(load_scene(path))


def test_open3d_says_nothing_on_stdout_about_a_file_that_is_no_mesh(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Open3D printed its reader's warning in colour on stdout (a `--json` reader's)."""
    path = _scene(tmp_path, "{class: seawall, file: meshes/block.obj, position_m: [0, 0]}")
    (tmp_path / "meshes" / "block.obj").write_text("v 1 2\nf x\n")
    with pytest.raises(SceneError):
        World(load_scene(path))
    assert capfd.readouterr().out == ""
