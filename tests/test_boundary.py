"""The typed stage boundary and the explicit graph (issue 36, items 3-5).

`Input` names and keys, `StageInputError` as exit 2 naming the file, the `Sensors` and
`ModelSettings` records, the graph built once at the CLI, commands importable.
"""

from __future__ import annotations

import ast
import pickle
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import toy_stages
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.commands._common import GraphChoice
from sonarmap.pipeline.engine.hashing import recipe_key, stage_recipe
from sonarmap.pipeline.engine.run.graph import Graph, load_graph
from sonarmap.pipeline.engine.run.planner import plan
from sonarmap.pipeline.engine.run.session import open_context
from sonarmap.pipeline.graph import default_graph
from sonarmap.schemas import SCHEMA_VERSION
from sonarmap.schemas.model_settings import ModelSettings
from sonarmap.schemas.recording import PoseTrack
from sonarmap.schemas.sensors import Sensors
from sonarmap.stages.base import DATASET, Input, Output, Stage, StageConfig, StageInputError
from sonarmap.stages.keyframes import STAGE as KEYFRAMES
from sonarmap.stages.keyframes import KeyframesConfig

ROOT = Path(__file__).resolve().parent.parent
MOUNT = [[1.0, 0, 0, 0.5], [0, 1.0, 0, 0], [0, 0, 1.0, -0.2], [0, 0, 0, 1.0]]
SENSORS = {
    "horizontal": {"T_base_sonar": MOUNT},
    "vertical": {
        "T_base_sonar": [[1.0, 0, 0, 0.5], [0, 0, -1.0, 0], [0, 1.0, 0, 0.1], [0, 0, 0, 1]]
    },
    "has_ground_truth": True,
    "has_labels": False,
    "source": {"format": "mcap", "name": "x"},
    "pairing": {"pairs": 3, "keyframes": 2},
}


class _Config(StageConfig):
    refuse: str = ""
    """Which input the stage refuses ("" none, "dataset", "upstream", "sensors": bad mount)."""


def _mount(config: _Config, inputs: dict[str, Any]) -> dict[str, Any]:
    if config.refuse == "dataset":
        raise StageInputError(DATASET, "the sonar never overlaps the navigation")
    sensors = dict(SENSORS)
    if config.refuse == "sensors":
        sensors["vertical"] = {"T_base_sonar": (2 * np.eye(4)).tolist()}
    n = len(inputs["dataset"])
    return {"table": pa.table({"v": np.arange(n, dtype=np.int64)}), "sensors": sensors}


def _use(config: _Config, inputs: dict[str, Any]) -> dict[str, Any]:
    if config.refuse == "upstream":
        raise StageInputError(Input("mount", "table"), "column v has nulls\nsecond line")
    sensors = inputs["mount.sensors"]
    assert isinstance(sensors, Sensors)  # the engine hands over the record, not the dict
    return {"summary": {"x_m": float(sensors.horizontal.T_base_sonar[0, 3])}}


GRAPH = Graph(
    stages=(
        Stage(
            "mount",
            1,
            _Config,
            (DATASET,),
            (
                Output("table", "parquet", "table.parquet"),
                Output("sensors", "json", "sensors.json", record=Sensors),
            ),
            _mount,
        ),
        Stage(
            "use",
            1,
            _Config,
            (Input("mount", "table"), Input("mount", "sensors")),
            (Output("summary", "json", "summary.json"),),
            _use,
        ),
    ),
    parts=lambda p: [p],
    open=lambda p, _section: p.read_bytes(),
)


def _cli(graph: Graph, *args: str) -> Any:
    return CliRunner().invoke(app, list(args), obj=GraphChoice(None, graph))


def test_input_names_are_the_dotted_text_the_keys_hashed() -> None:
    assert Input("keyframes", "sensors").name == "keyframes.sensors"
    assert Input.parse("keyframes.sensors") == Input("keyframes", "sensors")
    assert DATASET.name == "dataset" and Input.parse("dataset") is DATASET
    with pytest.raises(ValueError, match=r"expected '<stage>\.<output>'"):
        Input.parse("keyframes")
    # Declared as strings (older code), inputs are read as Inputs.
    legacy = Stage("s", 1, _Config, ("dataset", "a.b"), (), _use, input_columns=(("a.b", ("v",)),))
    assert legacy.inputs == (DATASET, Input("a", "b"))
    assert legacy.input_columns == ((Input("a", "b"), ("v",)),)
    assert legacy.upstream == ("a",) and legacy.reads_dataset


def test_a_key_hashes_the_same_text_as_when_inputs_were_strings(tmp_path: Path) -> None:
    data = tmp_path / "raw.bin"
    data.write_bytes(b"abc")
    ctx = open_context(data, toy_stages.GRAPH, store_dir=tmp_path / "store")
    planned = {p.stage.name: p for p in plan(ctx.stages, ctx.config, ctx.dataset, ctx.store)}
    expected = stage_recipe(
        stage="double",
        version=1,
        config={"factor": 2, "sleep_s": 0.0},
        input_keys={"source.table": planned["source"].key},
        schema_version=SCHEMA_VERSION,
    )
    assert planned["double"].key == recipe_key(expected)


def test_every_real_stage_declares_typed_inputs_and_the_graph_travels_to_workers() -> None:
    graph = default_graph()
    for stage in graph.config_stages:
        assert all(isinstance(i, Input) for i in stage.inputs), stage.name
    assert graph.stages[0].inputs == (DATASET,)
    # Sweep workers get the graph with their run (pickled by a process pool or Ray).
    assert pickle.loads(pickle.dumps(graph)).config_stages == graph.config_stages


def test_a_stage_refusing_the_recording_exits_2_naming_it(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(b"xyz")
    res = _cli(
        GRAPH, "run", str(data), "--store", str(tmp_path / "s"), "--set", "mount.refuse=dataset"
    )
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert lines == [
        f"error: {data}: the sonar never overlaps the navigation (input of stage mount)"
    ]
    assert "Traceback" not in res.output


def test_a_stage_refusing_an_artifact_exits_2_naming_its_file(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(b"xyz")
    store = tmp_path / "s"
    res = _cli(GRAPH, "run", str(data), "--store", str(store), "--set", "use.refuse=upstream")
    assert res.exit_code == 2, res.output
    (key,) = [p.name for p in (store / "mount").iterdir()]
    assert res.stderr.strip().splitlines()[-1] == (
        f"error: {data}: column v has nulls (input of stage use: mount/{key[:12]}/table.parquet)"
    )
    assert (store / "mount" / key / "manifest.json").is_file()  # what was computed stays


def test_bad_sensors_json_is_refused_at_binding_as_bad_input(tmp_path: Path) -> None:
    data = tmp_path / "rec.bin"
    data.write_bytes(b"xyz")
    store = tmp_path / "s"
    res = _cli(GRAPH, "run", str(data), "--store", str(store), "--set", "mount.refuse=sensors")
    assert res.exit_code == 2, res.output
    assert "sensors.vertical.T_base_sonar is not a 4x4 rigid transform" in res.stderr
    assert "/sensors.json)" in res.stderr  # the artifact file behind it, after the recording
    ok = _cli(GRAPH, "run", str(data), "--store", str(tmp_path / "s2"), "--json")
    assert ok.exit_code == 0, ok.output


def test_sensors_record_reads_sensors_json_and_gives_it_back() -> None:
    sensors = Sensors.from_json(SENSORS)
    assert sensors.to_json() == SENSORS
    assert Sensors.of(sensors) is sensors
    np.testing.assert_array_equal(sensors.horizontal.T_base_sonar, np.asarray(MOUNT))
    assert not sensors.horizontal.T_base_sonar.flags.writeable
    T = np.linalg.inv(np.asarray(MOUNT)) @ np.asarray(SENSORS["vertical"]["T_base_sonar"])
    np.testing.assert_allclose(sensors.T_h_v, T)
    assert sensors.has_ground_truth and sensors.source["name"] == "x"
    with pytest.raises(ValueError, match=r"sensors has no vertical\.T_base_sonar"):
        Sensors.from_json({"horizontal": SENSORS["horizontal"]})  # as the engine reads it
    partial = Sensors.of({"horizontal": SENSORS["horizontal"]})
    with pytest.raises(ValueError, match=r"sensors has no vertical\.T_base_sonar"):
        _ = partial.vertical
    for bad, match in (
        ({"horizontal": {"T_base_sonar": [[1, 2], [3, 4]]}}, "4x4"),
        ({"horizontal": {"T_base_sonar": "eye"}}, "4x4"),
        ({"horizontal": {}}, "has no horizontal.T_base_sonar"),
        ({**SENSORS, "has_labels": "yes"}, "has_labels is not true or false"),
        ([1, 2], "not a JSON object"),
    ):
        with pytest.raises(ValueError, match=match):
            Sensors.from_json(bad)


def test_model_settings_read_the_model_files_config() -> None:
    config = {"size_px": 40, "margin_m": 0.2, "min_side_m": 1.0, "eps_m": 0.25, "channels": [8]}
    settings = ModelSettings.from_config(config)
    assert (settings.size_px, settings.margin_m, settings.eps_m) == (40, 0.2, 0.25)
    assert settings.min_samples is None  # an older model file: classify's config must say
    assert settings.patch_normalisation == "peak"  # written before issue 50: its patches
    newer = ModelSettings.from_config({**config, "patch_normalisation": "background"})
    assert newer.patch_normalisation == "background"
    grain = ModelSettings.from_config({**config, "patch_normalisation": "grain"})
    assert grain.patch_normalisation == "grain"
    with pytest.raises(ValueError, match="'patch_normalisation' is not one of"):
        ModelSettings.from_config({**config, "patch_normalisation": "median"})
    with pytest.raises(ValueError, match="has no 'margin_m'"):
        ModelSettings.from_config({"size_px": 40, "min_side_m": 1.0})
    with pytest.raises(ValueError, match="'size_px' is not a positive int"):
        ModelSettings.from_config({**config, "size_px": True})


class _Recording:
    """A recording whose sonar pings all fall before its navigation starts."""

    name = "offset"

    def ping_times_ns(self, role: str) -> np.ndarray:
        return np.arange(5, dtype=np.int64) * 100_000_000 + (0 if role == "horizontal" else 1)

    def navigation(self) -> PoseTrack:
        t = 10**10 + np.arange(10, dtype=np.int64) * 100_000_000
        return PoseTrack(t, np.zeros((10, 3)), np.zeros((10, 3)))


def test_a_recording_whose_sonar_misses_its_navigation_is_refused_input() -> None:
    with pytest.raises(StageInputError, match=r"5 sonar pairs .* 0 inside the navigation") as err:
        KEYFRAMES.run(KeyframesConfig(), {"dataset": _Recording()})
    assert err.value.input == DATASET


def test_the_graph_variable_is_read_only_by_the_cli() -> None:
    readers = []
    for path in sorted((ROOT / "pipeline").rglob("*.py")):
        text = path.read_text()
        tree = ast.parse(text)
        environ = any(
            isinstance(n, ast.Attribute) and n.attr in ("environ", "getenv") for n in ast.walk(tree)
        )
        if environ and ("GRAPH_ENV" in text or "SONARMAP_GRAPH" in text):
            readers.append(path.relative_to(ROOT).as_posix())
        assert "functools.cache" not in text or path.name != "graph.py"
    assert readers == ["pipeline/cli.py"]


def test_the_cli_builds_the_named_graph_once(
    toy_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sonarmap.pipeline.engine.run.graph as engine_graph

    built: list[str | None] = []
    real = engine_graph.load_graph
    monkeypatch.setattr(
        engine_graph, "load_graph", lambda spec, default: built.append(spec) or real(spec, default)
    )
    res = CliRunner().invoke(app, ["run", str(toy_cli), "--store", str(tmp_path / "s"), "-q"])
    assert res.exit_code == 0, res.output
    assert built == ["toy_stages:GRAPH"]
    assert load_graph("toy_stages:GRAPH", default_graph).spec == "toy_stages:GRAPH"


def test_a_command_is_an_importable_module_level_function() -> None:
    from sonarmap.pipeline.commands.status import status

    callbacks = {c.name: c.callback for c in app.registered_commands}
    assert callbacks["status"] is status
    # (`convert` is another area's module, not converted yet)
    lifted = [c.callback for c in app.registered_commands if c.name != "convert"]
    assert all(f.__qualname__ == f.__name__ for f in lifted)


def test_the_dataset_walks_from_the_run_command_to_the_first_stage_through_few_modules(
    toy_cli: Path, tmp_path: Path
) -> None:
    stacks: dict[str, list[str]] = {}
    targets = {toy_stages._open.__code__: "opened", toy_stages._source.__code__: "source"}

    def modules(frame: FrameType | None) -> list[str]:
        names: list[str] = []
        while frame is not None:
            name = Path(frame.f_code.co_filename)
            if name.is_relative_to(ROOT) and (not names or names[-1] != name.stem):
                names.append(name.stem)
            if frame.f_code.co_name == "run" and name.stem == "run":
                break
            frame = frame.f_back
        return names[::-1]

    def profile(frame: FrameType, event: str, _arg: Any) -> None:
        if event == "call" and frame.f_code in targets:
            stacks.setdefault(targets[frame.f_code], modules(frame))

    sys.setprofile(profile)
    try:
        # One worker: the profile hook sees this thread only.
        args = ["run", str(toy_cli), "--store", str(tmp_path / "s"), "-q", "--workers", "1"]
        res = CliRunner().invoke(app, args)
    finally:
        sys.setprofile(None)
    assert res.exit_code == 0, res.output
    # The runner schedules the stage on a slot (`workers`), whose job (`compute`) opens
    # the dataset with the graph's `open` and calls the stage itself (no store callback,
    # no opener closure in the session).
    chain = ["run", "api", "runner", "workers", "runner", "workers", "compute", "toy_stages"]
    assert stacks == {"opened": chain, "source": chain}
