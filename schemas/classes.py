"""Object classes shared by the simulator's labels, the classifier and the maps.

Class id 0 means "nothing"; ids are stable because label images store them.
"""

from __future__ import annotations

__all__ = [
    "ASSIGNABLE_CLASSES",
    "CLASS_IDS",
    "CLASS_NAMES",
    "PILING_CLASSES",
    "UNKNOWN_CLASS",
    "class_name",
    "known_class_names",
]

CLASS_NAMES: tuple[str, ...] = (
    "none",
    "cylindrical_piling",
    "rectangular_piling",
    "seawall",
    "boat_hull",
    "truss",
    "seafloor",
)
"""Index = class id as stored in label images (uint8)."""

CLASS_IDS: dict[str, int] = {name: i for i, name in enumerate(CLASS_NAMES)}
PILING_CLASSES: tuple[str, ...] = ("cylindrical_piling", "rectangular_piling")
UNKNOWN_CLASS = "unknown"
"""Name given to objects the classifier is not confident about."""
ASSIGNABLE_CLASSES: frozenset[str] = frozenset(CLASS_NAMES) | {UNKNOWN_CLASS}
"""Every class an object (and so a map point) can carry."""


def known_class_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """`names` unchanged when each is in ASSIGNABLE_CLASSES; else ValueError naming the rest
    (for config validators)."""
    unknown = sorted(set(names) - ASSIGNABLE_CLASSES)
    if unknown:
        raise ValueError(f"unknown classes {unknown}; known: {sorted(ASSIGNABLE_CLASSES)}")
    return names


def class_name(class_id: int) -> str:
    """Name of a label-image class id (ValueError for an id outside the table)."""
    if not 0 <= class_id < len(CLASS_NAMES):
        raise ValueError(f"class id {class_id} outside 0..{len(CLASS_NAMES) - 1}")
    return CLASS_NAMES[class_id]
