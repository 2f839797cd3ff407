"""The class table: object classes shared by the simulator's labels, the classifier and the maps.

The table is data, held in the config's top-level section `classes` (`ClassTable`); its
default is the table below, and the module-level names (`CLASS_NAMES`, `CLASS_IDS`, ...)
are that default's views, for code that only ever sees the default (tests, fixtures).

Class id 0 means "nothing"; ids are stable because label images store them (uint8), and
stay below the map's reserved codes (`sonarmap.stages.kernels.map_codes`: 254 none, 255 unknown).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

__all__ = [
    "ASSIGNABLE_CLASSES",
    "CLASS_IDS",
    "CLASS_NAMES",
    "DEFAULT_TABLE",
    "MAX_CLASS_ID",
    "PILING_CLASSES",
    "TABLE_NAME",
    "UNKNOWN_CLASS",
    "ClassEntry",
    "ClassTable",
    "class_name",
    "known_class_names",
]

UNKNOWN_CLASS = "unknown"
"""Name given to objects the classifier is not confident about (reserved: no table entry)."""
TABLE_NAME = "classes.table"
"""How messages name the table (its config key)."""
MAX_CLASS_ID = 253
"""Largest table id: 254 and 255 are the map's codes for none and unknown."""
_NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")

FrameKindOrNone = Literal["object", "beam", "none"]


class ClassEntry(BaseModel):
    """One row of the class table."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(description="class name: lower case, digits and '_', 1-40 characters")
    id: int = Field(ge=0, le=MAX_CLASS_ID, description="label id stored in label images (uint8)")
    frame_kind: FrameKindOrNone = Field(
        "object",
        description="reference frame of its height model: 'object' (ICP-registered object"
        " frame, paper Sec. IV.D), 'beam' (per-beam leading edge) or 'none' (never inferred)",
    )
    inferred: bool = Field(False, description="whether infer learns a height model by default")
    completeness: bool = Field(
        False, description="whether evaluate measures its surface completeness by default"
    )
    colour: str = Field("#808080", description="colour in figures, '#rrggbb'")

    @field_validator("id", mode="before")
    @classmethod
    def _number_not_boolean(cls, value: Any) -> Any:
        # strict as every config section is: pydantic's lax mode read `id: true` as 1
        if isinstance(value, bool):
            raise ValueError("expected a number, not a boolean")
        return value

    @field_validator("inferred", "completeness", mode="before")
    @classmethod
    def _strict_flag(cls, value: Any) -> Any:
        if not isinstance(value, bool):  # lax: 1, "true", "yes" read as true
            raise ValueError("expected true or false")
        return value

    @field_validator("name")
    @classmethod
    def _sane_name(cls, value: str) -> str:
        if not _NAME.match(value):
            raise ValueError(
                f"class name {value[:40]!r}: lower case letters, digits and '_', 1-40 characters"
            )
        return value

    @field_validator("colour")
    @classmethod
    def _hex_colour(cls, value: str) -> str:
        if not re.fullmatch(r"#[0-9a-fA-F]{6}", value):
            raise ValueError(f"colour {value[:20]!r}: expected '#rrggbb'")
        return value.lower()

    @model_validator(mode="after")
    def _inferred_has_a_frame(self) -> ClassEntry:
        if self.inferred and self.frame_kind == "none":
            raise ValueError(f"class {self.name}: inferred needs frame_kind object or beam")
        return self


def _entry(name: str, id: int, frame: FrameKindOrNone, colour: str, **flags: bool) -> ClassEntry:
    return ClassEntry(name=name, id=id, frame_kind=frame, colour=colour, **flags)


DEFAULT_ENTRIES: tuple[ClassEntry, ...] = (
    _entry("none", 0, "none", "#000000"),
    _entry("cylindrical_piling", 1, "object", "#e41a1c", inferred=True, completeness=True),
    _entry("rectangular_piling", 2, "object", "#ff7f00", inferred=True, completeness=True),
    _entry("seawall", 3, "beam", "#4daf4a", inferred=True),
    _entry("boat_hull", 4, "beam", "#377eb8"),
    _entry("truss", 5, "beam", "#984ea3"),
    _entry("seafloor", 6, "none", "#a6a6a6"),
)
"""Today's table: what every label image written so far means."""


class ClassTable(BaseModel):
    """Config section `classes`: the class table (names, label ids, frames, colours).

    `add` appends entries to `table` (folded in on load, so a config extends the default
    table without repeating it). Validated: unique names and ids, id 0 is 'none',
    'unknown' reserved, ids below the map's reserved codes.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    KEY_OMITS_DEFAULT: ClassVar[bool] = True
    """Stages that read this section hash it only when it differs from the default, so the
    default table leaves every key as it was before the table was configurable."""

    DRAWING_FIELDS: ClassVar[tuple[str, ...]] = ("colour",)
    """Entry fields that change only how a class is drawn: they enter the keys of the
    stages that draw (`Stage.draws`), not those of the stages that compute (a new colour
    must not retrain the classifier)."""

    table: tuple[ClassEntry, ...] = Field(
        DEFAULT_ENTRIES,
        description="the classes: none, cylindrical_piling, rectangular_piling, seawall,"
        " boat_hull, truss, seafloor (ids 0-6)",
    )
    add: tuple[ClassEntry, ...] = Field(
        (), description="entries appended to table (empty after loading: folded into table)"
    )

    @model_validator(mode="before")
    @classmethod
    def _fold_add(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("add"):
            try:
                added = [ClassEntry.model_validate(e) for e in data["add"]]
            except (ValidationError, TypeError):
                return data  # refused as `add` itself: the error names add[i], not table[7+i]
            base = data.get("table", DEFAULT_ENTRIES)
            data = {**data, "table": (*base, *added), "add": ()}
        return data

    @model_validator(mode="after")
    def _valid_table(self) -> ClassTable:
        names = [e.name for e in self.table]
        ids = [e.id for e in self.table]
        dup_names = sorted({n for n in names if names.count(n) > 1})
        dup_ids = sorted({i for i in ids if ids.count(i) > 1})
        if dup_names or dup_ids:
            dup = f"duplicate {'names' if dup_names else 'ids'} {dup_names or dup_ids}"
            raise ValueError(f"{TABLE_NAME}: {dup}")
        if UNKNOWN_CLASS in names:
            raise ValueError(
                f"{TABLE_NAME}: '{UNKNOWN_CLASS}' is reserved (objects the classifier doubts)"
            )
        if 0 not in ids or self.table[ids.index(0)].name != "none":
            raise ValueError(f"{TABLE_NAME}: id 0 must be the class 'none'")
        return self

    @property
    def names(self) -> tuple[str, ...]:
        """Class names in table order."""
        return tuple(e.name for e in self.table)

    @property
    def ids(self) -> dict[str, int]:
        """Name -> label id."""
        return {e.name: e.id for e in self.table}

    @property
    def assignable(self) -> frozenset[str]:
        """Every class an object (and so a map point) can carry: the table and 'unknown'."""
        return frozenset(self.names) | {UNKNOWN_CLASS}

    def entry(self, name: str) -> ClassEntry:
        return self.table[self.names.index(name)]

    def name_of(self, class_id: int) -> str:
        """Name of a label id (ValueError naming the table for an id outside it)."""
        for e in self.table:
            if e.id == class_id:
                return e.name
        raise ValueError(f"class id {class_id} is not in the class table ({TABLE_NAME})")

    def names_by_id(self) -> list[str]:
        """Index = label id (0..max id), name or '' where no class has that id."""
        out = [""] * (max(e.id for e in self.table) + 1)
        for e in self.table:
            out[e.id] = e.name
        return out

    @property
    def inferred(self) -> tuple[str, ...]:
        """Classes infer learns a height model for by default, in table order."""
        return tuple(e.name for e in self.table if e.inferred)

    @property
    def completeness(self) -> tuple[str, ...]:
        """Classes whose completeness evaluate measures by default."""
        return tuple(e.name for e in self.table if e.completeness)

    def frame_kinds(self) -> dict[str, Literal["object", "beam"]]:
        """Class -> frame kind of every class with one ('unknown' takes the beam frame)."""
        kinds: dict[str, Literal["object", "beam"]] = {
            e.name: e.frame_kind for e in self.table if e.frame_kind != "none"
        }
        return {**kinds, UNKNOWN_CLASS: "beam"}

    def check(self, names: Iterable[str], where: str, unknown_ok: bool = True) -> None:
        """ValueError naming `where` and the table when a name is not a class of it."""
        allowed = self.assignable if unknown_ok else frozenset(self.names)
        bad = sorted({n for n in names if n not in allowed})
        if bad:
            prefix = f"{where}: " if where else ""
            raise ValueError(
                f"{prefix}unknown class {bad[0][:40]!r}, not in the class table ({TABLE_NAME}:"
                f" {', '.join(self.names)})"
            )


DEFAULT_TABLE = ClassTable()
"""The default table (today's classes)."""

CLASS_NAMES: tuple[str, ...] = DEFAULT_TABLE.names
"""Default table: index = class id as stored in label images (uint8)."""
CLASS_IDS: dict[str, int] = DEFAULT_TABLE.ids
PILING_CLASSES: tuple[str, ...] = DEFAULT_TABLE.completeness
ASSIGNABLE_CLASSES: frozenset[str] = DEFAULT_TABLE.assignable
"""Default table: every class an object (and so a map point) can carry."""


def known_class_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """`names` unchanged when each is a sane class name (config validators; whether each
    is in the run's table is checked against its `classes` section when the config loads)."""
    bad = [n for n in names if n != UNKNOWN_CLASS and not _NAME.match(n)]
    if bad:
        raise ValueError(f"class name {bad[0][:40]!r} is not a class name")
    return names


def class_name(class_id: int, table: ClassTable = DEFAULT_TABLE) -> str:
    """Name of a label-image class id (ValueError for an id outside the table)."""
    return table.name_of(class_id)
