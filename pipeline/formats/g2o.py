"""Reader for planar pose graphs in the g2o and TORO text formats.

g2o: ``VERTEX_SE2 id x y theta`` and ``EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33``
(upper triangle of the information matrix, row by row).
TORO: ``VERTEX2 id x y theta`` and ``EDGE2 i j dx dy dtheta I11 I12 I22 I33 I13 I23``
(a different order: the rotation terms come last).

Both describe the measurement of pose j in the frame of pose i (``T_i^{-1} T_j``) with
tangent order (x, y, theta), which is GTSAM's `Pose2` order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sonarmap.pipeline.engine.errors import SourceError

__all__ = ["PoseGraph2D", "read_pose_graph"]

_G2O_ORDER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_TORO_ORDER = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))
_VERTEX_TAGS = {"VERTEX_SE2", "VERTEX2"}
_EDGE_TAGS = {"EDGE_SE2": _G2O_ORDER, "EDGE2": _TORO_ORDER}
_IGNORED_TAGS = {"FIX", "EQUIV"}


@dataclass(frozen=True)
class PoseGraph2D:
    """A planar pose graph as arrays.

    Attributes:
        vertex_ids: (N,) int64 vertex ids, ascending.
        poses: (N, 3) float64 initial poses (x_m, y_m, theta_rad) in the world frame.
        edge_from: (M,) int64 id of the edge's first vertex i.
        edge_to: (M,) int64 id of the edge's second vertex j.
        measurements: (M, 3) float64 pose of j in the frame of i (x_m, y_m, theta_rad).
        information: (M, 3, 3) float64 symmetric information matrices, order (x, y, theta).
    """

    vertex_ids: np.ndarray
    poses: np.ndarray
    edge_from: np.ndarray
    edge_to: np.ndarray
    measurements: np.ndarray
    information: np.ndarray


def _floats(values: list[str], count: int, where: str) -> list[float]:
    if len(values) != count:
        raise SourceError(f"{where}: expected {count} numbers, found {len(values)}")
    try:
        out = [float(v) for v in values]
    except ValueError as err:
        raise SourceError(f"{where}: not a number ({err})") from err
    if not np.all(np.isfinite(out)):
        raise SourceError(f"{where}: non-finite number")
    return out


MAX_GRAPH_BYTES = 256 << 20
"""Largest pose graph read (a million vertices and edges is some 100 MB of text)."""


def _vertex_id(token: str, where: str) -> int:
    try:
        return int(token)
    except ValueError as err:
        raise SourceError(f"{where}: vertex id {token!r} is not an integer") from err


def read_pose_graph(path: str | Path) -> PoseGraph2D:
    """Read a g2o (``VERTEX_SE2``/``EDGE_SE2``) or TORO (``VERTEX2``/``EDGE2``) 2D graph.

    Args:
        path: the text file.

    Returns:
        The graph with vertices sorted by id and edges in file order.

    Raises:
        SourceError: the file is missing or a line is malformed (message names file and line),
            an edge names an unknown vertex, a vertex repeats, or the file holds no vertex.
    """
    path = Path(path)
    from sonarmap.pipeline.engine.user_files import read_user_file

    raw = read_user_file(path, "pose graph", SourceError, MAX_GRAPH_BYTES)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SourceError(f"{path}: cannot read pose graph ({err})") from err
    vertices: dict[int, list[float]] = {}
    edges: list[tuple[int, int, list[float], np.ndarray]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#") or tokens[0] in _IGNORED_TAGS:
            continue
        where = f"{path}:{number}"
        tag = tokens[0]
        if tag in _VERTEX_TAGS:
            vid = _vertex_id(tokens[1] if len(tokens) > 1 else "", where)
            if vid in vertices:
                raise SourceError(f"{where}: vertex {vid} defined twice")
            vertices[vid] = _floats(tokens[2:], 3, where)
        elif tag in _EDGE_TAGS:
            if len(tokens) < 3:
                raise SourceError(f"{where}: {tag} needs two vertex ids")
            i, j = _vertex_id(tokens[1], where), _vertex_id(tokens[2], where)
            values = _floats(tokens[3:], 9, where)
            info = np.zeros((3, 3))
            for (r, c), v in zip(_EDGE_TAGS[tag], values[3:], strict=True):
                info[r, c] = info[c, r] = v
            edges.append((i, j, values[:3], info))
        else:
            raise SourceError(f"{where}: unknown record {tag!r} (expected VERTEX_SE2/EDGE_SE2)")
    if not vertices:
        raise SourceError(f"{path}: no VERTEX_SE2 or VERTEX2 record")
    for i, j, *_ in edges:
        for vid in (i, j):
            if vid not in vertices:
                raise SourceError(f"{path}: edge {i}->{j} names unknown vertex {vid}")
    ids = np.array(sorted(vertices), dtype=np.int64)
    return PoseGraph2D(
        vertex_ids=ids,
        poses=np.array([vertices[int(v)] for v in ids], dtype=np.float64).reshape(-1, 3),
        edge_from=np.array([e[0] for e in edges], dtype=np.int64),
        edge_to=np.array([e[1] for e in edges], dtype=np.int64),
        measurements=np.array([e[2] for e in edges], dtype=np.float64).reshape(-1, 3),
        information=np.array([e[3] for e in edges], dtype=np.float64).reshape(-1, 3, 3),
    )
