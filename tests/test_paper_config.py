"""configs/paper.yaml: the paper's protocol as a valid pipeline config, every line sourced."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.graph import all_stages, extra_sections
from sonarmap.stages.classify.stage import ClassifyConfig
from sonarmap.stages.fuse.stage import FuseConfig

PAPER = Path(__file__).resolve().parents[1] / "configs" / "paper.yaml"
SOURCE = re.compile(r"paper (Sec\.|Eq\.|Table)|orig §\d")


def _leaves(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_paper_config_validates_and_every_value_takes_effect() -> None:
    config = load_config(all_stages(), PAPER, (), extra_sections())
    resolved = config.model_dump(mode="json")
    written = _leaves(yaml.safe_load(PAPER.read_text()))
    assert len(written) >= 25
    for dotted, value in written.items():
        section, field = dotted.split(".")
        assert resolved[section][field] == value, dotted
    # The protocol's core choices (brief of the issue; sources in the file).
    assert config.keyframes.spacing_m == 4.0
    assert config.slam.mode == "ground_truth"
    assert config.fuse.confidence_rule == "ratio" and config.fuse.max_cost_ratio == 0.97
    assert config.classify.pool_views is False and config.classify.threshold == 0.99
    assert config.infer.range_axis == "offset"
    assert list(config.infer.classes) == ["cylindrical_piling", "rectangular_piling"]
    assert CliRunner().invoke(app, ["config", "check", str(PAPER)]).exit_code == 0


def test_every_key_line_of_the_paper_config_names_its_source() -> None:
    lines = PAPER.read_text().splitlines()
    keys = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    assert keys
    for line in keys:
        value, sep, comment = line.partition("  # ")
        assert sep, f"no comment: {line!r}"
        assert ":" in value, f"not a key line: {line!r}"
        assert SOURCE.search(comment), f"comment names no paper section or orig §: {line!r}"


def test_the_protocol_options_are_off_by_default() -> None:
    fuse, classify = FuseConfig(), ClassifyConfig()
    assert fuse.min_subproblem_features == 1
    assert fuse.confidence_rule == "paper" and fuse.max_cost_ratio is None
    assert classify.min_object_area_m2 is None and classify.drop_fan_edge_objects is False
