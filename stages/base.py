"""The stage contract: what the engine needs to know about a stage, nothing more.

A stage is a pure function `run(config, inputs) -> outputs` over in-memory values
(Arrow tables, dicts, bytes, sequences of `KeyframeImages`), plus the metadata the
engine hashes into the artifact key. Stages never see paths, never print, never
import the engine.
"""

from __future__ import annotations

import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from sonarmap.stages.kernels.lazy import resolve

__all__ = [
    "DATASET",
    "UNITS_INPUT",
    "USER_SETTINGS",
    "ConfigModel",
    "Input",
    "Output",
    "OutputKind",
    "Stage",
    "StageConfig",
    "StageInputError",
    "StageSettingsError",
    "Units",
]

OutputKind = Literal["parquet", "json", "bytes", "frames"]
"""How the engine stores an output.

- parquet: a `pyarrow.Table`, written sorted as given, no timestamps in metadata.
- json: a JSON-serialisable dict (canonical, sorted keys).
- bytes: opaque bytes written verbatim (PNG, PLY, TUM text, torch state dict, ...).
- frames: an iterable of `sonarmap.schemas.sonar.KeyframeImages`, stored as ROS 2 MCAP and
  read back lazily as a sequence.
"""


def _scalar_types(annotation: Any) -> set[Any]:
    """The scalar types an annotation admits, through Optional, Annotated and containers."""
    origin = typing.get_origin(annotation)
    if origin is None:
        return {annotation} if isinstance(annotation, type) else set()
    if origin is Literal:
        return set()
    if origin is Annotated:
        return _scalar_types(typing.get_args(annotation)[0])
    return set().union(*(_scalar_types(a) for a in typing.get_args(annotation)))


def _holds_bool(value: Any) -> bool:
    if isinstance(value, (list, tuple)):
        return any(_holds_bool(v) for v in value)
    return isinstance(value, bool)


@dataclass(frozen=True, order=True)
class Input:
    """One input of a stage: output `output` of upstream stage `stage`, or the raw
    recording (`DATASET`).

    `name` ("<stage>.<output>", or "dataset") is the key the stage's `run` finds the
    value under, and the text hashed into the stage's key (unchanged from when inputs
    were written as dotted strings, so keys stay the same).
    """

    stage: str
    output: str

    @property
    def name(self) -> str:
        return "dataset" if self == DATASET else f"{self.stage}.{self.output}"

    @property
    def is_dataset(self) -> bool:
        return self == DATASET

    @classmethod
    def parse(cls, name: str) -> Input:
        """The input named `name` ("<stage>.<output>" or "dataset")."""
        if name == "dataset":
            return DATASET
        stage, dot, output = name.partition(".")
        if not (stage and dot and output):
            raise ValueError(f"input {name[:80]!r}: expected '<stage>.<output>' or 'dataset'")
        return cls(stage, output)

    def __str__(self) -> str:
        return self.name


DATASET = Input("", "dataset")
"""The raw recording (bound to the first stage, opened with its config section)."""


UNITS_INPUT = "units"
"""Where a stage declaring `units=True` finds its `Units` memo in `run`'s inputs (absent
when the stage is called directly: it then computes everything)."""


class Units(typing.Protocol):
    """Per-keyframe work units a stage caches (the engine's memo; the stage sees no path).

    The stage computes each key (sha256 of everything the unit depends on: its version,
    the config fields it reads, the keyframe's own content, any global value it uses) and
    stores plain numeric arrays under it; `get` gives them back, or None. A stage reading
    the dataset keys its whole-recording units by `dataset`, the dataset's content
    fingerprint (the one its artifacts are keyed by).
    """

    dataset: str

    def get(self, key: str) -> Mapping[str, Any] | None: ...
    def put(self, key: str, arrays: Mapping[str, Any]) -> None: ...


class StageInputError(ValueError):
    """A stage refuses one of its inputs as bad data (not a bug in the stage).

    The engine reports it as bad input (exit 2): one line with the stage's `reason`,
    naming the file behind `input` (the artifact's file, or the recording).
    """

    def __init__(self, input: Input | str, reason: str) -> None:
        self.input = input if isinstance(input, Input) else Input.parse(input)
        self.reason = reason
        super().__init__(f"{self.input.name}: {reason}")


class StageSettingsError(ValueError):
    """The stage's settings cannot run on this data (bad input, not a bug in the stage):
    a solver that cannot solve the graph they make, more memory than a run may take. The
    engine reports it as a config error (exit 2): one line, naming the settings."""


class ConfigModel(BaseModel):
    """Base of every config model: frozen, unknown keys refused, finite numbers only.

    Booleans are strict both ways: a flag takes only true/false (not 1, "yes"), and a
    number is never a boolean (pydantic's lax mode would read `spacing_m: true` as 1.0).
    Every number carries `gt`/`ge` and `le`/`lt` bounds in its own `Field`.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _strict_booleans(cls, value: Any, info: ValidationInfo) -> Any:
        if info.field_name is None or value is None:
            return value
        kinds = _scalar_types(cls.model_fields[info.field_name].annotation) - {type(None)}
        if kinds == {bool} and not isinstance(value, bool):
            raise ValueError("expected true or false")
        if kinds & {int, float} and bool not in kinds and _holds_bool(value):
            raise ValueError("expected a number, not a boolean")
        return value


class StageConfig(ConfigModel):
    """Base of every stage config section. Units in field names."""


USER_SETTINGS = "user_settings"
"""Serialisation context flag (`model_dump(context={USER_SETTINGS: True})`): the settings
as a user gives them (`config dump`), where a key holds what a setting reads instead (the
thresholds of `features.calibration_from`, not its path)."""


@dataclass(frozen=True)
class Output:
    """One named output of a stage and the file it is stored in.

    `optional` outputs may be returned as None (e.g. a ground-truth mesh that a
    field dataset does not carry); the engine then writes no file and later binds None.
    """

    name: str
    kind: OutputKind
    filename: str
    optional: bool = False
    schema: Any = None
    """For parquet outputs: the `pyarrow.Schema` from `schemas/` the table must match
    (the engine validates column names and types before committing), or its name as
    `module:NAME` (e.g. "sonarmap.schemas.map:MAP_SCHEMA"), so declaring the stage imports no
    pyarrow; `arrow_schema` is the schema either way."""
    record: Any = None
    """For json outputs: a record type from `schemas/` (`from_json(doc)`, `to_json()`)
    that readers of the output receive instead of the dict (e.g. `sonarmap.schemas.sensors.Sensors`),
    or its `module:NAME`; the file holds the dict as written."""

    @property
    def arrow_schema(self) -> Any:
        """`schema`, imported when given by name (None: not declared)."""
        return resolve(self.schema)

    @property
    def record_type(self) -> Any:
        """`record`, imported when given by name (None: readers get the dict)."""
        return resolve(self.record)


@dataclass(frozen=True)
class Stage:
    """A pipeline stage.

    Attributes:
        name: stage name, also the config section and the store folder.
        version: bumped by hand whenever the output could change (helpers included).
        config: the frozen pydantic model of this stage's config section.
        inputs: what the engine binds, as `Input`s: `DATASET` (the raw recording, first
            stage only) or `Input(stage, output)` of an upstream stage; `run` finds each
            under its `Input.name`. (Dotted strings are read as `Input.parse` reads them.)
        outputs: what `run` returns, by name.
        run: `run(config, inputs) -> {output name: value}`; a stage package declares
            it as `sonarmap.stages.kernels.lazy.deferred("stages.<name>.stage:run")`, so planning
            imports the declaration (`stages/<name>/__init__.py`) and never the compute.
        key_excludes: fields of the stage's own section that do not enter its key, because
            the stage never reads them (they configure a later stage that lists the
            section in `reads_sections`, e.g. `keyframes.submap_stride`), or because they
            change how, never what, it computes (`submaps.workers`; a test holds the
            bytes equal).
        reads_sections: other config sections the stage reads: bound as inputs
            `config.<section>` and hashed into its key (a section's `DRAWING_FIELDS`
            only when the stage `draws`).
        draws: the stage draws figures with the sections it reads (their colours).
        dataset_section: the section the "dataset" input is opened with (None: its own).
        input_columns: (input, columns) pairs: read only these columns of a Parquet input
            (a stage that needs a few columns of a large table).
        units: the stage caches per-keyframe work units: the engine binds a `Units` memo
            under `UNITS_INPUT`, and the artifact's manifest lists the units it used
            (`sonarmap.pipeline.engine.store.units`).
        off_critical_path: nothing in the graph waits for its outputs (the figures): with
            several workers the runner gives it a worker process when one is idle, so the
            slot in the runner's own process, where the dataset is already open, stays
            free for the stages that read it.
    """

    name: str
    version: int
    config: type[StageConfig]
    inputs: tuple[Input, ...]
    outputs: tuple[Output, ...]
    run: Callable[[Any, Mapping[str, Any]], Mapping[str, Any]]
    description: str = ""
    key_excludes: tuple[str, ...] = ()
    reads_sections: tuple[str, ...] = ()
    dataset_section: str | None = None
    input_columns: tuple[tuple[Input, tuple[str, ...]], ...] = ()
    off_critical_path: bool = False
    units: bool = False
    draws: bool = False

    def __post_init__(self) -> None:
        def typed(item: Input | str) -> Input:
            return Input.parse(item) if isinstance(item, str) else item

        object.__setattr__(self, "inputs", tuple(map(typed, self.inputs)))
        columns = tuple((typed(i), tuple(c)) for i, c in self.input_columns)
        object.__setattr__(self, "input_columns", columns)

    @property
    def upstream(self) -> tuple[str, ...]:
        """Names of the upstream stages this stage reads from (in input order, unique)."""
        return tuple(dict.fromkeys(i.stage for i in self.inputs if not i.is_dataset))

    @property
    def reads_dataset(self) -> bool:
        return DATASET in self.inputs
