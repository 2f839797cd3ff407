"""The class table in config (issue 38, item 1): validated, in the keys, used everywhere."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from sonarmap.pipeline.engine.config.load import load_config, section_dict
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.graph import all_stages, extra_sections, stage_by_name
from sonarmap.pipeline.labels.files import export_labels, import_labels
from sonarmap.schemas.annotations import AnnotationFile
from sonarmap.schemas.classes import DEFAULT_TABLE, ClassTable
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.sim.scene import load_scene
from sonarmap.sim.world import World
from sonarmap.stages.classify.annotations import rasterise
from sonarmap.stages.kernels.class_models import DEFAULT_FRAME_KINDS
from sonarmap.stages.kernels.map_codes import class_ids

MOORING = "classes:\n  add:\n    - {name: mooring_block, id: 7, frame_kind: object, inferred: true, colour: '#8c564b'}\n"  # fmt: skip
READERS = ("classify", "train", "infer", "submaps", "voxelize", "evaluate")
"""Every stage whose outputs depend on the class table."""


def _config(tmp_path: Path, text: str, overrides: tuple[str, ...] = ()) -> object:
    path = tmp_path / "config.yaml"
    path.write_text(text)
    return load_config(all_stages(), path, overrides, extra_sections())


def test_the_default_table_is_todays() -> None:
    assert DEFAULT_TABLE.names == (
        "none", "cylindrical_piling", "rectangular_piling", "seawall", "boat_hull", "truss",
        "seafloor",
    )  # fmt: skip
    assert [DEFAULT_TABLE.ids[n] for n in DEFAULT_TABLE.names] == list(range(7))
    assert DEFAULT_TABLE.inferred == ("cylindrical_piling", "rectangular_piling", "seawall")
    assert DEFAULT_TABLE.completeness == ("cylindrical_piling", "rectangular_piling")
    assert DEFAULT_FRAME_KINDS == {
        "cylindrical_piling": "object", "rectangular_piling": "object", "seawall": "beam",
        "boat_hull": "beam", "truss": "beam", "unknown": "beam",
    }  # fmt: skip
    # The default config's infer section resolves to exactly today's classes and frames.
    infer = load_config(all_stages(), None, (), extra_sections()).infer  # type: ignore[attr-defined]
    resolved = infer.with_table(DEFAULT_TABLE)
    assert resolved.classes == DEFAULT_TABLE.inferred
    assert resolved.frame_kinds == DEFAULT_FRAME_KINDS


@pytest.mark.parametrize(
    ("entries", "says"),
    [
        ("- {name: none, id: 0}\n  - {name: rock, id: 0}", "duplicate ids [0]"),
        ("- {name: none, id: 0}\n  - {name: none, id: 1}", "duplicate names ['none']"),
        ("- {name: rock, id: 0}", "id 0 must be the class 'none'"),
        ("- {name: none, id: 0}\n  - {name: unknown, id: 1}", "'unknown' is reserved"),
        ("- {name: none, id: 0}\n  - {name: rock, id: 254}", "must be >= 0 and <= 253"),
        ("- {name: none, id: 0}\n  - {name: Big Rock, id: 1}", "lower case letters"),
        ("- {name: none, id: 0}\n  - {name: rock, id: 1, colour: red}", "expected '#rrggbb'"),
        ("- {name: none, id: 0}\n  - {name: rock, id: 1, inferred: true, frame_kind: none}",
         "inferred needs frame_kind"),
    ],
)  # fmt: skip
def test_a_bad_table_is_refused_in_one_line_naming_it(
    tmp_path: Path, entries: str, says: str
) -> None:
    with pytest.raises(ConfigError) as err:
        _config(tmp_path, f"classes:\n  table:\n  {entries}\n")
    message = str(err.value)
    assert "\n" not in message
    assert "classes.table" in message and says in message


def test_a_colour_moves_only_the_key_of_the_stage_that_draws(tmp_path: Path) -> None:
    """A new colour retrained the classifier and recomputed every class reader (campaign 8)."""
    from sonarmap.pipeline.engine.config.load import section_dict as keyed

    default = load_config(all_stages(), None, (), extra_sections())
    table = "\n".join(
        f"    - {{name: {e.name}, id: {e.id}, frame_kind: {e.frame_kind},"
        f" inferred: {str(e.inferred).lower()}, completeness: {str(e.completeness).lower()},"
        f" colour: '{'#123456' if e.name == 'seawall' else e.colour}'}}"
        for e in DEFAULT_TABLE.table
    )
    recoloured = _config(tmp_path, f"classes:\n  table:\n{table}\n")
    assert recoloured.classes != default.classes  # type: ignore[attr-defined]
    for name in (*READERS, "figures"):
        stage = stage_by_name(name)
        args = (name, stage.key_excludes, stage.reads_sections, stage.draws)
        same = keyed(default, *args) == keyed(recoloured, *args)  # type: ignore[arg-type]
        assert same != (name == "figures"), name


def test_keys_change_with_the_table_and_the_default_leaves_them_as_they_were(
    tmp_path: Path,
) -> None:
    default = load_config(all_stages(), None, (), extra_sections())
    extended = _config(tmp_path, MOORING)
    for name in READERS:
        stage = stage_by_name(name)
        args = (name, stage.key_excludes, stage.reads_sections)
        before, after = section_dict(default, *args), section_dict(extended, *args)  # type: ignore[arg-type]
        assert "classes" in stage.reads_sections
        assert before != after, name
        # The default table is not hashed: keys stay those of the hard-coded table.
        assert "classes" not in before.get("@reads", {}), name
    # A stage that reads no class never sees the table.
    kf = stage_by_name("keyframes")
    assert section_dict(default, "keyframes", kf.key_excludes) == section_dict(
        extended,  # type: ignore[arg-type]
        "keyframes",
        kf.key_excludes,
    )
    # `add` folds into the table: the same table written out in full is the same config.
    full = ClassTable(table=(*DEFAULT_TABLE.table, *extended.classes.table[7:]))  # type: ignore[attr-defined]
    assert full == extended.classes  # type: ignore[attr-defined]


def test_an_unknown_class_anywhere_in_config_is_refused_naming_the_table(tmp_path: Path) -> None:
    for override in (
        "infer.classes=rock",
        "infer.frame_kinds={rock: beam}",
        "infer.borrowed_models={rock: seawall}",
        "voxelize.evidence_classes=rock",
        "evaluate.completeness_classes=rock",
    ):
        with pytest.raises(ConfigError, match=r"unknown class 'rock'.*classes\.table"):
            _config(tmp_path, "{}\n", (override,))
    # Borrowing is judged with the classes the table gives infer, when the config loads.
    with pytest.raises(ConfigError, match=r"infer: borrowed_models .*inferred beam-frame class"):
        _config(tmp_path, "{}\n", ("infer.borrowed_models={truss: cylindrical_piling}",))
    quay = "classes:\n  add:\n    - {name: quay_wall, id: 9, frame_kind: beam, inferred: true}\n"
    lent = _config(tmp_path, quay, ("infer.borrowed_models={truss: quay_wall}",))
    assert lent.infer.with_table(lent.classes).borrowed_models == {"truss": "quay_wall"}  # type: ignore[attr-defined]
    # Defined in the table, the same class is accepted (and becomes an inferred class).
    cfg = _config(tmp_path, MOORING, ("infer.frame_kinds={mooring_block: beam}",))
    infer = cfg.infer.with_table(cfg.classes)  # type: ignore[attr-defined]
    assert infer.classes == (*DEFAULT_TABLE.inferred, "mooring_block")
    assert infer.frame_kind("mooring_block") == "beam"
    assert infer.frame_kind("seawall") == "beam"


def _ping(t_ns: int) -> SonarPing:
    ranges = (np.arange(120) * 0.1 + 0.5).astype(np.float32)
    angles = np.deg2rad(np.linspace(-60, 60, 96)).astype(np.float32)
    return SonarPing(t_ns, "horizontal", np.full((120, 96), 3, np.uint8), ranges, angles)


def test_labels_coco_and_maps_use_the_table(tmp_path: Path) -> None:
    table = _config(tmp_path, MOORING).classes  # type: ignore[attr-defined]
    doc = {
        "keyframes": [
            {"t_ns": 1_000, "objects": [{"class_name": "mooring_block", "box_m": {
                "x_min_m": 5.0, "x_max_m": 6.0, "y_min_m": -0.5, "y_max_m": 0.5}}]},
        ]
    }  # fmt: skip
    # An annotation file naming a class the table lacks is refused, naming the table.
    with pytest.raises(ValueError, match=r"unknown class 'mooring_block'.*classes\.table"):
        AnnotationFile.model_validate(doc)
    labels = AnnotationFile.model_validate(doc, context={"classes": table})
    cells = rasterise(_ping(1_000), labels.keyframes[0].objects, table)
    assert set(np.unique(cells).tolist()) == {0, 7}
    # COCO: the table's classes are the categories; import needs the same table.
    frame = KeyframeImages(0, 1_000, _ping(1_000), _ping(1_000))
    shapes = {0: labels.keyframes[0].objects}
    (tmp_path / "dive.mcap").write_bytes(b"a recording")  # import writes beside it
    done = export_labels(tmp_path / "dive.mcap", tmp_path / "out", [frame], {0: 1_000}, shapes, table.ids, 1.0)  # fmt: skip
    categories = {c["name"]: c["id"] for c in json.loads(done.coco.read_text())["categories"]}
    assert categories["mooring_block"] == 7
    with pytest.raises(Exception, match=r"unknown class 'mooring_block'.*classes\.table"):
        import_labels(done.coco)
    _, imported = import_labels(done.coco, table=table)
    assert imported.keyframes == labels.keyframes
    # Map codes: the table's id, 255 for a class it lacks.
    names = pa.array(["mooring_block", "seawall", "unknown"])
    assert class_ids(names, table).tolist() == [7, 3, 255]
    assert class_ids(names).tolist() == [255, 3, 255]


def test_a_scene_of_a_class_the_table_lacks_is_refused_naming_it(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "b.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"
    )
    path = tmp_path / "site.yaml"
    path.write_text(
        "name: site\nseafloor_depth_m: 6.0\narea_m: [-10, 10, -10, 10]\nobjects: []\n"
        "meshes:\n  - {class: mooring_block, file: meshes/b.obj, position_m: [2, 2]}\n"
    )
    scene = load_scene(path)
    with pytest.raises(
        ValueError, match=r"'mooring_block' is not in the class table.*classes\.table"
    ):
        World(scene)
    table = _config(tmp_path, MOORING).classes  # type: ignore[attr-defined]
    world = World(scene, table=table)
    assert (world.objects[0].class_id, world.objects[0].class_name) == (7, "mooring_block")
