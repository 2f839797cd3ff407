"""A recording's transform tree (`/tf_static`, `/tf`): compose base_link -> any frame.

Edges are (parent, child, (4, 4) T_parent_child). A frame's mount is the product of the
transforms along the unique path from the base frame to it; the path may run against
an edge's direction (then that edge's inverse is used), so a tree published child-first
(e.g. sonar_mount -> base_link) composes as well. `/tf` edges are static mounts only when
they never change, so the first value of each edge is used and a changing one is marked
(the reader warns when a mount's chain runs through one).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

__all__ = ["TfConflict", "TfTree", "normalise_frame"]


class TfConflict(ValueError):
    """A transform that contradicts the tree (a second parent for a frame)."""


def normalise_frame(frame: str) -> str:
    """A frame id as tf2 compares them: without a leading slash (ROS 1 style)."""
    return frame.strip().lstrip("/")


@dataclass
class TfTree:
    """Undirected graph of frames; `chain`/`lookup` give base -> frame transforms."""

    edges: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    changing: set[tuple[str, str]] = field(default_factory=set)
    parents: dict[str, str] = field(default_factory=dict)
    _group: dict[str, str] = field(default_factory=dict)

    def _root(self, frame: str) -> str:
        while self._group.get(frame, frame) != frame:
            frame = self._group[frame]
        return frame

    def _check_new_link(self, parent: str, child: str) -> None:
        """Refuse a link between frames the tree already connects: two ways from one
        frame to another give two mounts (a child published first, e.g. sonar -> mount,
        is one way and allowed)."""
        other = self.parents.get(child)
        if self._root(parent) == self._root(child):
            if other is not None and other != parent:
                raise TfConflict(
                    f"frame {child!r} has two parents, {other!r} and {parent!r} (a frame "
                    "has one parent in a tf tree; remove one of the transforms)"
                )
            raise TfConflict(
                f"transform {parent} -> {child} closes a loop: the tree already joins "
                "them another way (remove one of the transforms)"
            )
        self.parents.setdefault(child, parent)
        self._group[self._root(child)] = self._root(parent)

    def add(self, parent: str, child: str, T: np.ndarray) -> None:
        """Add an edge; a repeated edge with another value is kept first and marked.

        Raises:
            TfConflict: `child` already has another parent (tf2 allows one; which mount
                is meant cannot be known).
        """
        key = (normalise_frame(parent), normalise_frame(child))
        if key not in self.edges and key[::-1] not in self.edges:
            self._check_new_link(*key)
        if key in self.edges:
            if not np.allclose(self.edges[key], T, atol=1e-6):
                self.changing.add(key)
            return
        self.edges[key] = np.asarray(T, np.float64)

    def add_all(self, edges: Iterable[tuple[str, str, np.ndarray]]) -> None:
        for parent, child, T in edges:
            self.add(parent, child, T)

    @property
    def frames(self) -> list[str]:
        """Every frame named by an edge, sorted."""
        return sorted({f for edge in self.edges for f in edge})

    def changing_on(self, chain: list[str]) -> list[tuple[str, str]]:
        """The edges along `chain` whose value changed (see `add`)."""
        steps = list(pairwise(chain))
        return [e for a, b in steps for e in ((a, b), (b, a)) if e in self.changing]

    def chain(self, base: str, frame: str) -> list[str] | None:
        """Frames from `base` to `frame` (both included), or None when not connected."""
        base, frame = normalise_frame(base), normalise_frame(frame)
        if base == frame:
            return [base]
        neighbours: dict[str, list[str]] = {}
        for parent, child in self.edges:
            neighbours.setdefault(parent, []).append(child)
            neighbours.setdefault(child, []).append(parent)
        previous: dict[str, str] = {base: base}
        queue = deque([base])
        while queue:
            cur = queue.popleft()
            for nb in sorted(neighbours.get(cur, [])):
                if nb not in previous:
                    previous[nb] = cur
                    queue.append(nb)
        if frame not in previous:
            return None
        path = [frame]
        while path[-1] != base:
            path.append(previous[path[-1]])
        return path[::-1]

    def lookup(self, base: str, frame: str) -> tuple[np.ndarray, list[str]] | None:
        """(T_base_frame, chain) composed along the chain, or None when not connected."""
        path = self.chain(base, frame)
        if path is None:
            return None
        T: np.ndarray | None = None
        for a, b in pairwise(path):
            step = self.edges[(a, b)] if (a, b) in self.edges else np.linalg.inv(self.edges[(b, a)])
            # The first link is used as it is (no product with the identity), so a one-link
            # tree gives exactly the transform the recording holds.
            T = step if T is None else T @ step
        return (np.eye(4) if T is None else T), path
