"""Pipeline configuration: one YAML file, one section per stage, CLI overrides.

The effective config is a frozen pydantic model whose fields are the stages' own
config models (defaults are documented once, in those models). A stage's key
hashes only its own section, so changing `fuse.*` never recomputes `features`.
"""

from __future__ import annotations

import difflib
import functools
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model

from sonarmap.pipeline.engine.config.validation import short, validation_message
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.engine.text import one_line
from sonarmap.stages.base import USER_SETTINGS, Stage

__all__ = [
    "apply_overrides",
    "check_class_names",
    "config_model_for",
    "dump_yaml",
    "load_config",
    "parse_override",
    "section_dict",
    "user_settings",
]


@functools.cache
def _model_for(
    stages: tuple[Stage, ...], extras: tuple[tuple[str, type[BaseModel]], ...] = ()
) -> type[BaseModel]:
    fields: dict[str, Any] = {s.name: (s.config, s.config()) for s in stages}
    # Built per config, not once: a section's defaults may read the environment (the
    # `training` section's cache directory, `$SONARMAP_CACHE_DIR`).
    fields.update({name: (model, Field(default_factory=model)) for name, model in extras})
    model: type[BaseModel] = cast(Any, create_model)(
        "PipelineConfig",
        __config__=ConfigDict(frozen=True, extra="forbid"),
        **fields,
    )
    return model


def config_model_for(
    stages: Sequence[Stage], extra_sections: Mapping[str, type[BaseModel]] | None = None
) -> type[BaseModel]:
    """The frozen pydantic model with one section per stage (cached per stage tuple).

    `extra_sections` are engine-level sections that are not stages (e.g. `training`,
    the datasets the default classifier learns from).
    """
    return _model_for(tuple(stages), tuple(sorted((extra_sections or {}).items())))


READ_SECTIONS_KEY = "@reads"
"""Key of a stage's key config under which the other sections it reads are hashed (no
config field can be named so)."""


def section_dict(
    config: BaseModel,
    stage: str,
    excludes: Iterable[str] = (),
    reads_sections: Iterable[str] = (),
    draws: bool = False,
) -> dict[str, Any]:
    """A stage's resolved section as plain JSON-compatible data (what its key hashes).

    `excludes`: own fields the stage never reads (left out of its key); `reads_sections`:
    other sections the stage reads, hashed under READ_SECTIONS_KEY, their
    `DRAWING_FIELDS` only for a stage that `draws`.
    """
    section = getattr(config, stage)
    data: dict[str, Any] = section.model_dump(mode="json", exclude=set(excludes) or None)
    reads = {}
    for name in reads_sections:
        read = getattr(config, name)
        dropped = () if draws else getattr(type(read), "DRAWING_FIELDS", ())
        dump = _without(read.model_dump(mode="json"), dropped)
        # A section that says so (`KEY_OMITS_DEFAULT`, the class table) is left out of
        # keys where it equals its default: its default keeps keys as they were.
        omits_default = getattr(type(read), "KEY_OMITS_DEFAULT", False)
        if omits_default and dump == _without(type(read)().model_dump(mode="json"), dropped):
            continue
        reads[name] = dump
    if reads:
        data[READ_SECTIONS_KEY] = reads
    return data


def _without(data: Any, fields: Iterable[str]) -> Any:
    """`data` (JSON-like) with every mapping's `fields` left out, at any depth."""
    fields = tuple(fields)
    if not fields:
        return data
    if isinstance(data, dict):
        return {k: _without(v, fields) for k, v in data.items() if k not in fields}
    if isinstance(data, list):
        return [_without(v, fields) for v in data]
    return data


def check_class_names(config: BaseModel, where: str) -> None:
    """Every class name a section holds (`class_names_used()`) is in the config's class
    table (section `classes`); ConfigError naming the field and the table otherwise."""
    table = getattr(config, "classes", None)
    if table is None:
        return
    for section_name in type(config).model_fields:
        section = getattr(config, section_name)
        used = getattr(section, "class_names_used", None)
        if used is None:
            continue
        for field, names in used().items():
            try:
                table.check(names, f"{section_name}.{field}")
            except ValueError as err:
                raise ConfigError(f"{where}: {err}") from err
        # A section whose defaults come from the table is validated as the stage sees it.
        resolve = getattr(section, "with_table", None)
        try:
            if resolve is not None:
                resolve(table)
        except ValidationError as err:
            message = str(err.errors()[0]["msg"]).removeprefix("Value error, ")
            raise ConfigError(f"{where}: {section_name}: {one_line(message)}") from err


MOVED_KEYS: dict[str, str] = {
    "classify.overlay": "figures.overlay",
    "features.calibration_pings": "keyframes.calibration_pairs",
}
"""Config keys that moved to another section: an old key is refused naming the new one."""


def _closest(name: str, candidates: Iterable[str]) -> str:
    if name in MOVED_KEYS:
        return f" (moved to '{MOVED_KEYS[name]}')"
    match = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.5)
    return f" (did you mean '{match[0]}'?)" if match else ""


def _field_annotation(model: type[BaseModel], path: list[str], where: str) -> Any:
    """Walk nested models along `path`; ConfigError naming the closest key on a miss."""
    current: Any = model
    for i, part in enumerate(path):
        fields = getattr(current, "model_fields", None)
        dotted = one_line(".".join(path[: i + 1]), MAX_KEY_CHARS)
        if fields is None:
            raise ConfigError(f"{where}: '{dotted}' is not a config section")
        if part not in fields:
            prefix = ".".join(path[:i])
            names = [f"{prefix}.{f}" if prefix else f for f in fields]
            moved = dotted in MOVED_KEYS  # says where it went, not where a namesake is
            hint = (not moved and _in_another_section(model, path)) or _closest(dotted, names)
            raise ConfigError(f"{where}: unknown key '{dotted}'{hint}")
        current = _section_of(fields[part].annotation)
    return current


def _in_another_section(model: type[BaseModel], path: list[str]) -> str:
    """` (did you mean 'slam.nssm_window_xy_m'?)` when `section.field` names a field that
    another section has (a close name in the wrong section is the likelier slip)."""
    if len(path) != 2:
        return ""
    found = [
        f"{name}.{path[1]}"
        for name, f in model.model_fields.items()
        if name != path[0] and path[1] in getattr(_section_of(f.annotation), "model_fields", {})
    ]
    return f" (did you mean '{found[0]}'?)" if len(found) == 1 else ""


def _section_of(annotation: Any) -> Any:
    """An optional section (`Model | None`, null switches it off) walks as its model."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        models = [a for a in typing.get_args(annotation) if hasattr(a, "model_fields")]
        if len(models) == 1:
            return models[0]
    return annotation


def _is_sequence_type(annotation: Any) -> bool:
    origin = typing.get_origin(annotation)
    if origin in (list, tuple, set, frozenset, Sequence):
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_is_sequence_type(a) for a in typing.get_args(annotation) if a is not type(None))
    return False


def is_list_key(model: type[BaseModel], key: str) -> bool:
    """Whether the setting `section.field` holds a list (False for a key `model` does not
    have: loading the config names it then, with the closest key)."""
    try:
        return _is_sequence_type(_field_annotation(model, key.strip().split("."), key))
    except ConfigError:
        return False


def parse_override(model: type[BaseModel], text: str) -> tuple[list[str], Any]:
    """Parse `section.field=value` into (path, typed value); lists are written `a,b`.

    Values are read as YAML scalars (`4` -> int, `true` -> bool, `null` -> None) and
    pydantic then coerces them to the field's type.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"override {short(text)}: expected section.field=value")
    path = key.strip().split(".")
    where = f"--set {one_line(key.strip(), MAX_KEY_CHARS)}"
    annotation = _field_annotation(model, path, where)
    if len(raw) > MAX_OVERRIDE_CHARS:
        raise ConfigError(f"{where}: value of {len(raw)} characters (at most {MAX_OVERRIDE_CHARS})")
    try:  # a shell's non-UTF-8 bytes arrive as lone surrogates, which no parser encodes
        raw.encode("utf-8")
    except UnicodeEncodeError as err:
        bad = ord(raw[err.start])
        at = len(raw[: err.start].encode("utf-8", "surrogateescape"))
        shown = f" (byte {at} is {bad - 0xDC00:#04x})" if 0xDC80 <= bad <= 0xDCFF else ""
        raise ConfigError(f"{where}: the value is not UTF-8 text{shown}") from None
    if _is_sequence_type(annotation) and not raw.strip().startswith("["):
        return path, [_scalar(v, where) for v in raw.split(",") if v.strip() != ""]
    return path, _scalar(raw, where)


MAX_KEY_CHARS = 80
"""Longest `--set` key quoted in a message."""

MAX_OVERRIDE_CHARS = 1 << 16
"""Longest `--set` value (a list of a few hundred numbers fits easily)."""


def _scalar(raw: str, where: str) -> Any:
    """A `--set` value read as YAML by the bounded loader; text that is not YAML stays text.

    Refusals (aliases, duplicate keys, deep nesting, huge integers) are errors, not text.
    """
    if not raw.strip():
        return ""
    from sonarmap.pipeline.engine.config.yaml_files import YamlRefused, load_yaml_text

    try:
        value = load_yaml_text(raw, where, "value", ConfigError)
    except ConfigError as err:
        if isinstance(err.__cause__, YamlRefused):
            raise
        return raw
    if isinstance(value, str) and "\n" in raw:  # YAML folds a line break into a space
        return raw.strip()
    return value


def _refuse_repeats(parsed: Sequence[tuple[list[str], Any]]) -> None:
    """A `--set` that overwrites an earlier one: the same setting twice, or a section after
    a setting in it (the earlier value would silently go, as a duplicate key of a YAML
    file's would). A setting after its section refines it, and is kept."""
    seen: list[list[str]] = []
    for path, _ in parsed:
        for other in seen:
            if other[: len(path)] == path:
                first, second = ".".join(other), ".".join(path)
                also = "given twice" if first == second else f"then its section {second}"
                raise ConfigError(
                    f"--set {one_line(first, MAX_KEY_CHARS)}: {also} (the last would silently"
                    " win); give each setting once"
                )
        seen.append(path)


def apply_overrides(data: dict[str, Any], overrides: Iterable[tuple[list[str], Any]]) -> None:
    """Set each (path, value) in the nested dict `data` in place."""
    for path, value in overrides:
        node = data
        for part in path[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                child = {}
                node[part] = child
            node = child
        node[path[-1]] = value


def _check_keys(model: type[BaseModel], data: Mapping[str, Any], where: str, prefix: str) -> None:
    fields = model.model_fields
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        if key not in fields:
            names = [f"{prefix}{f}" for f in fields]
            if not isinstance(key, str) or len(dotted) > MAX_KEY_CHARS:
                raise ConfigError(f"{where}: unknown key {short(dotted)}")
            raise ConfigError(f"{where}: unknown key '{one_line(dotted)}'{_closest(dotted, names)}")
        sub = fields[key].annotation
        if isinstance(value, Mapping) and isinstance(sub, type) and issubclass(sub, BaseModel):
            _check_keys(sub, value, where, f"{dotted}.")


def load_config(
    stages: Sequence[Stage],
    path: Path | None = None,
    overrides: Sequence[str] = (),
    extra_sections: Mapping[str, type[BaseModel]] | None = None,
) -> BaseModel:
    """Read the YAML file (optional), apply `--set` overrides, validate.

    Raises:
        ConfigError: unreadable file, unknown section/key (with the closest valid
            name), or a value of the wrong type; the message names file and key.
    """
    model = config_model_for(stages, extra_sections)
    where = one_line(str(path)) if path else "config"
    data: dict[str, Any] = {}
    if path is not None:
        from sonarmap.pipeline.engine.config.yaml_files import (
            read_yaml,  # yaml: only when there is a file
        )

        loaded = read_yaml(path, "config", ConfigError)
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{where}: expected a mapping of stage sections")
        data = loaded or {}
        _check_keys(model, data, where, "")
    parsed = [parse_override(model, o) for o in overrides]
    _refuse_repeats(parsed)
    apply_overrides(data, parsed)
    try:
        config = model.model_validate(data)
    except ValidationError as err:
        loc = list(err.errors()[0]["loc"])
        # A bad value given on the command line is named as such, not as the file's.
        for key, _ in reversed(parsed):
            if loc[: len(key)] == key:
                where = f"--set {one_line('.'.join(key), MAX_KEY_CHARS)}"
                break
        raise ConfigError(validation_message(model, err, where)) from err
    check_class_names(config, where)
    return config


def dump_yaml(config: BaseModel) -> str:
    """The effective config as YAML (one section per stage, in stage order)."""
    import yaml

    return yaml.safe_dump(user_settings(config), sort_keys=False)


def user_settings(config: BaseModel) -> dict[str, Any]:
    """The config as settings, for a user to read or reuse (a keyed dump leaves out the
    paths whose content it holds instead)."""
    return config.model_dump(mode="json", context={USER_SETTINGS: True})
