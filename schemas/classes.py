"""Object classes shared by the simulator's labels, the classifier and the maps.

Class id 0 means "nothing"; ids are stable because label images store them.
"""

from __future__ import annotations

__all__ = ["CLASS_IDS", "CLASS_NAMES", "PILING_CLASSES", "UNKNOWN_CLASS", "class_name"]

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


def class_name(class_id: int) -> str:
    """Name of a label-image class id (ValueError for an id outside the table)."""
    if not 0 <= class_id < len(CLASS_NAMES):
        raise ValueError(f"class id {class_id} outside 0..{len(CLASS_NAMES) - 1}")
    return CLASS_NAMES[class_id]
