"""Config bounds (issue 23): every number bounded both ways, checked at and past its bounds.

Values go in the way a user types them (`--set section.field=value`, YAML files), through
`load_config` for the whole pipeline config, and through the CLI for exit codes.
"""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.pipeline.training.config import TrainingSet

runner = CliRunner()
ROOT = Path(__file__).resolve().parent.parent
COMPANIONS = {"fuse.max_cost_ratio": ["fuse.confidence_rule=ratio"]}
"""Overrides a value needs to be valid at all (cross-field rules of the model)."""


def _sections() -> list[tuple[str, type[BaseModel]]]:
    return [(s.name, s.config) for s in all_stages()] + sorted(extra_sections().items())


def _scalar(annotation: Any) -> tuple[Any, list[Any]]:
    """(type, bound metadata) through Optional and Annotated."""
    meta: list[Any] = []
    while True:
        args = typing.get_args(annotation)
        if typing.get_origin(annotation) is typing.Annotated:
            annotation = args[0]
            meta += [m for extra in args[1:] for m in getattr(extra, "metadata", [extra])]
        elif type(None) in args and len(args) == 2:
            annotation = next(a for a in args if a is not type(None))
        else:
            return annotation, meta


def numeric_fields() -> list[tuple[str, int | None, type, dict[str, Any]]]:
    """(dotted field, tuple index or None, int/float, {"gt"/"ge"/"lt"/"le": bound})."""
    out = []
    for section, model in _sections():
        for name, field in model.model_fields.items():
            kind, meta = _scalar(field.annotation)
            elements: list[tuple[int | None, Any, list[Any]]] = [(None, kind, meta)]
            if typing.get_origin(kind) is tuple:
                elements = [(i, *_scalar(a)) for i, a in enumerate(typing.get_args(kind))]
            for index, scalar, element_meta in elements:
                if scalar in (int, float):
                    bounds = {
                        k: getattr(m, k)
                        for m in [*field.metadata, *element_meta]
                        for k in ("gt", "ge", "lt", "le")
                        if getattr(m, k, None) is not None
                    }
                    out.append((f"{section}.{name}", index, scalar, bounds))
    return out


NUMERIC = numeric_fields()
IDS = [f"{n}[{i}]" if i is not None else n for n, i, _, _ in NUMERIC]


def _override(dotted: str, index: int | None, value: str) -> list[str]:
    extra = COMPANIONS.get(dotted, [])
    if index is None:
        return [*extra, f"{dotted}={value}"]
    section, name = dotted.split(".")
    current = getattr(getattr(_default(), section), name)
    if current is None:  # unset (e.g. a mount taken from the recording): any valid tuple
        kind, _ = _scalar(dict(_sections())[section].model_fields[name].annotation)
        current = [0] * len(typing.get_args(kind))
    default = list(current)
    items = [repr(v) for v in default]
    items[index] = value
    return [*extra, f"{dotted}=[{', '.join(items)}]"]


def _default() -> Any:
    return load_config(all_stages(), None, (), extra_sections())


def accepts(dotted: str, index: int | None, value: str) -> bool:
    try:
        load_config(all_stages(), None, _override(dotted, index, value), extra_sections())
    except ConfigError:
        return False
    return True


def _step(kind: type, bound: float) -> float:
    return 1 if kind is int else max(abs(bound) * 1e-6, 1e-9)


def test_every_number_has_a_lower_and_an_upper_bound() -> None:
    assert len(NUMERIC) > 100
    for dotted, index, _, bounds in NUMERIC:
        assert bounds.keys() & {"gt", "ge"}, f"{dotted}[{index}]: no lower bound"
        assert bounds.keys() & {"lt", "le"}, f"{dotted}[{index}]: no upper bound"


@pytest.mark.parametrize(("dotted", "index", "kind", "bounds"), NUMERIC, ids=IDS)
def test_number_at_its_bounds_is_accepted_and_past_them_refused(
    dotted: str, index: int | None, kind: type, bounds: dict[str, Any]
) -> None:
    for name, bound in bounds.items():
        step = _step(kind, bound) * (1 if name in ("gt", "ge") else -1)
        inside, outside = (bound, bound - step) if name in ("ge", "le") else (bound + step, bound)
        assert accepts(dotted, index, repr(inside)), f"{dotted} = {inside} refused ({name})"
        assert not accepts(dotted, index, repr(outside)), f"{dotted} = {outside} accepted"
    for bad in ("true", "false", ".nan", "nan", ".inf", "-.inf", "1e999", "'3'x"):
        assert not accepts(dotted, index, bad), f"{dotted} = {bad} accepted"


BOOLS = [
    f"{section}.{name}"
    for section, model in _sections()
    for name, field in model.model_fields.items()
    if field.annotation is bool
]


@pytest.mark.parametrize("dotted", BOOLS)
def test_booleans_are_strict(dotted: str) -> None:
    assert accepts(dotted, None, "true") and accepts(dotted, None, "false")
    for bad in ("1", "0", "'true'", "2.5", "null"):
        assert not accepts(dotted, None, bad), f"{dotted} = {bad} accepted"


def test_defaults_and_shipped_configs_stay_valid() -> None:
    load_config(all_stages(), None, (), extra_sections())
    for path in sorted((ROOT / "configs").glob("*.yaml")):
        load_config(all_stages(), path, (), extra_sections())
    TrainingSet(scene="harbour", seed=0, goals=1)


ISSUE_VALUES = [
    ("keyframes.spacing_m=-2", "> 0 and <= 1000"),
    ("keyframes.spacing_m=0", "> 0"),
    ("keyframes.spacing_m=true", "not a boolean"),
    ("keyframes.rotation_deg=-30", "> 0 and <= 360"),
    ("keyframes.min_gap_s=-1", ">= 0 and <= 3600"),
    ("keyframes.image_max_range_m=-30", "> 0"),
    ("keyframes.image_fov_deg=0", "> 0"),
    ("classify.seed=-1", ">= 0"),
    ("keyframes.spacing_m=1e18", "<= 1000"),
    ("classify.mc_passes=1000000000000", "<= 1000"),
    ("slam.icp_max_iterations=1000000000", "<= 10000"),
    ("voxelize.voxel_size_m=1e-300", ">= 0.001"),
    ("keyframes.pair_tolerance_s=-0.1", ">= 0 and <= 60"),
    ("infer.z_step_m=.nan", "finite number"),
]


@pytest.mark.parametrize(("override", "words"), ISSUE_VALUES)
def test_bad_value_is_one_line_naming_field_value_and_range(override: str, words: str) -> None:
    res = runner.invoke(app, ["config", "dump", "--set", override])
    assert res.exit_code == 2 and "Traceback" not in res.output
    line = res.stderr.strip()
    key, value = override.split("=")
    assert "\n" not in line and f"{key} = " in line and words in line, line
    assert value.lstrip(".") in line.lower() or value == "true", line


def test_whole_config_is_checked_before_any_stage_whatever_until_says(tmp_path: Path) -> None:
    store = tmp_path / "store"
    for override in ("evaluate.tolerance_m=.nan", "keyframes.pair_tolerance_s=-0.1"):
        args = ["run", str(tmp_path / "absent.mcap"), "--until", "keyframes", "--store", str(store)]
        res = runner.invoke(app, [*args, "--set", override])
        assert res.exit_code == 2 and override.split("=")[0] in res.stderr, res.output
    assert not (store / "keyframes").exists()


def test_sweep_checks_every_point_before_the_first_run(tmp_path: Path) -> None:
    store = str(tmp_path / "store")
    args = ["sweep", str(tmp_path / "a.mcap"), "--set", "keyframes.spacing_m=2,-4"]
    res = runner.invoke(app, [*args, "--store", store])
    assert res.exit_code == 2 and "keyframes.spacing_m = -4" in res.stderr, res.output


CONFIG_FILES = {
    "negative-spacing": ("keyframes:\n  spacing_m: -4\n", "keyframes.spacing_m = -4: must be > 0"),
    "unknown-scene": (
        "training:\n  sets:\n    - {scene: atlantis, seed: 1, goals: 2}\n",
        "training.sets[0].scene = 'atlantis': scene 'atlantis' not found",
    ),
    "non-utf8": (b"keyframes:\n  spacing_m: \xff\n", "not UTF-8 text (byte 24 is 0xff)"),
    "unclosed-list": ("keyframes:\n  spacing_m: [1,\n", "line 3:1"),
    "bad-indent": ("keyframes:\n  spacing_m: 2\n rotation_deg: 3\n", "line 3:2"),
    "tab": ("keyframes:\n\tspacing_m: 2\n", "line 2:1"),
    "duplicate-colon": ("keyframes: spacing_m: 2\n", "line 1:21"),
    "not-a-mapping": ("- keyframes\n", "expected a mapping"),
    "string-for-number": ("keyframes:\n  spacing_m: two\n", "keyframes.spacing_m = 'two'"),
}


@pytest.mark.parametrize("case", sorted(CONFIG_FILES))
def test_config_check_refuses_bad_files_in_one_line(case: str, tmp_path: Path) -> None:
    text, words = CONFIG_FILES[case]
    path = tmp_path / "bad.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    for args in (["config", "check", str(path)], ["config", "dump", "--config", str(path)]):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and "Traceback" not in res.output, res.output
        line = res.stderr.strip()
        assert "\n" not in line and str(path) in line and words in line, line


def test_config_check_accepts_a_dumped_default_and_a_directory_is_refused(tmp_path: Path) -> None:
    dumped = runner.invoke(app, ["config", "dump"])
    path = tmp_path / "defaults.yaml"
    path.write_text(dumped.stdout)
    assert runner.invoke(app, ["config", "check", str(path)]).exit_code == 0
    res = runner.invoke(app, ["config", "check", str(tmp_path)])
    assert res.exit_code == 2 and str(tmp_path) in res.stderr and "\n" not in res.stderr.strip()


SCENE_FILES = {
    "unclosed-list": ("name: x\nobjects: [a, b\n", "line 3:1"),
    "non-utf8": (b"name: \xff\n", "not UTF-8 text (byte 6 is 0xff)"),
    "not-a-mapping": ("- a\n", "must be a YAML mapping"),
    "missing-field": ("name: x\nobjects: []\n", "area_m"),
}


@pytest.mark.parametrize("case", sorted(SCENE_FILES))
def test_simulate_refuses_a_bad_scene_file_in_one_line(case: str, tmp_path: Path) -> None:
    text, words = SCENE_FILES[case]
    path = tmp_path / "scene.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    res = runner.invoke(app, ["simulate", "--scene", str(path), "-o", str(tmp_path / "x.mcap")])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    line = res.stderr.strip()
    assert "\n" not in line and str(path) in line and words in line, line
    assert not (tmp_path / "x.mcap").exists()


def test_a_set_text_keeps_its_line_break() -> None:
    """Campaign 15 #11: YAML folded a line break in a `--set` path into a space, so an
    existing file `a\\nb.json` was looked for as `a b.json` (a config file kept it)."""
    sets = ["features.calibration_from=bad/nl\nname.json", "keyframes.spacing_m=3"]
    config = load_config(all_stages(), None, sets, extra_sections())
    assert config.features.calibration_from == "bad/nl\nname.json"  # type: ignore[attr-defined]
    assert config.keyframes.spacing_m == 3.0  # type: ignore[attr-defined]
