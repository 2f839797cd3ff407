"""g2o / TORO pose-graph reader: real files, information-matrix orders, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.formats.g2o import read_pose_graph


@pytest.fixture
def posegraphs(shared_data: Path) -> Path:
    return shared_data / "posegraphs"


def test_reads_the_intel_dataset(posegraphs: Path) -> None:
    g = read_pose_graph(posegraphs / "intel.g2o")
    assert len(g.vertex_ids) == 1728 and len(g.edge_from) == 2512
    np.testing.assert_allclose(g.measurements[0], [0.144012, -0.004462, -0.017453])
    np.testing.assert_allclose(
        g.information[0],
        [[115.187, -9.86523, -7.085], [-9.86523, 347.418, 185.36], [-7.085, 185.36, 224.616]],
    )
    assert np.all(np.linalg.eigvalsh(g.information) > 0)


def test_reads_toro_and_gtsam_example_files(posegraphs: Path) -> None:
    toro = read_pose_graph(posegraphs / "w100.graph")
    assert len(toro.vertex_ids) == 100 and len(toro.edge_from) == 300
    np.testing.assert_allclose(toro.information[0], np.eye(3))
    example = read_pose_graph(posegraphs / "pose2example.txt")
    np.testing.assert_allclose(np.diag(example.information[0]), [44.72136, 44.72136, 30.901699])


def test_information_orders_differ_between_formats(tmp_path: Path) -> None:
    values = "1 2 3 4 5 6"
    g2o = tmp_path / "a.g2o"
    g2o.write_text(f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 {values}\n")
    toro = tmp_path / "a.graph"
    toro.write_text(f"VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 {values}\n")
    np.testing.assert_array_equal(
        read_pose_graph(g2o).information[0], [[1, 2, 3], [2, 4, 5], [3, 5, 6]]
    )  # I11 I12 I13 I22 I23 I33
    np.testing.assert_array_equal(
        read_pose_graph(toro).information[0], [[1, 2, 5], [2, 3, 6], [5, 6, 4]]
    )  # I11 I12 I22 I33 I13 I23


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("VERTEX_SE2 0 0 0\n", "a.g2o:1: expected 3 numbers"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "unknown vertex 1"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 x 0 0 0\n", "a.g2o:2: vertex id 'x'"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE3:QUAT 0 1\n", "a.g2o:2: unknown record"),
        ("VERTEX_SE2 0 0 0 nan\n", "a.g2o:1: non-finite"),
        ("# only a comment\n", "no VERTEX_SE2"),
    ],
)
def test_bad_input_names_the_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "a.g2o"
    path.write_text(text)
    with pytest.raises(SourceError, match=message.replace(".", r"\.").replace("(", r"\(")):
        read_pose_graph(path)


def test_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="cannot read"):
        read_pose_graph(tmp_path / "absent.g2o")
