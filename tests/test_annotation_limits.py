"""Hostile annotation files (issue 34 items 3, 4, 10, 11, 15): refused as one line naming
the file and the field or line:column; times that match no keyframe are bad input."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.training.annotations import ANNOTATIONS_MAX_BYTES, load_annotations
from sonarmap.schemas.annotations import AnnotationFile
from sonarmap.schemas.sonar import KeyframeImages, SonarPing
from sonarmap.stages.classify.annotations import UnmatchedAnnotations, label_keyframes

ROOT = Path(__file__).resolve().parent.parent
HEAD = "format: sonarmap-annotations/1\n"
BOX = "{class_name: seawall, box_m: {x_min_m: 1, x_max_m: 2, y_min_m: -1, y_max_m: 1}}"


def _entry(t_ns: object) -> str:
    return f"  - t_ns: {t_ns}\n    objects: [{BOX}]\n"


def _refused(tmp_path: Path, text: str, *words: str) -> str:
    path = tmp_path / "field.annotations.yaml"
    path.write_text(text)
    with pytest.raises(SourceError) as err:
        load_annotations(path)
    msg = str(err.value)
    assert err.value.exit_code == 2 and "\n" not in msg and len(msg) < 400, msg[:500]
    assert msg.startswith(f"{path}: "), msg
    for word in words:
        assert word in msg, msg
    return msg


@pytest.mark.parametrize(
    ("text", "words"),
    [
        # QA: a second `keyframes:` trained on the second list only.
        (HEAD + "keyframes:\n" + _entry(5) + "keyframes:\n" + _entry(6),
         ["line 5:1", "duplicate key 'keyframes'", "first at line 2:1"]),
        (HEAD + "keyframes:\n  - t_ns: 5\n    t_ns: 6\n", ["line 3:5", "duplicate key 't_ns'"]),
        ('{"format": "sonarmap-annotations/1", "keyframes": [], "keyframes": []}',
         ["duplicate key 'keyframes'"]),
        # An alias bomb: each level repeats the one before nine times.
        (HEAD + "o: &o " + BOX + "\nkeyframes:\n  - {t_ns: 5, objects: [*o, *o, *o]}\n",
         ["line 2:4", "anchor &o refused"]),
        (HEAD + "keyframes: " + "[" * 1500 + "]" * 1500 + "\n", ["line 2:"]),
        (HEAD + "keyframes:\n" + _entry("9" * 5000), ["line 3:11", "integer of 5000 characters"]),
        (HEAD + "keyframes:\n" + _entry(2**63), ["keyframes[0].t_ns", "less than or equal to"]),
        (HEAD + "keyframes:\n" + _entry(-1), ["keyframes[0].t_ns", "greater than or equal to 0"]),
        (HEAD + "keyframes:\n  - {t_ns: 5, objects: [{class_name: '" + "q" * 100_000 + "'}]}\n",
         ["keyframes[0].objects[0].class_name", "unknown class 'qqq"]),
    ],
    ids=["dup-keyframes", "dup-t_ns", "dup-json", "alias-bomb", "deep", "huge-int", "t_ns-2^63",
         "t_ns-negative", "huge-class-name"],
)  # fmt: skip
def test_a_hostile_annotation_file_is_one_line_naming_file_and_place(
    tmp_path: Path, text: str, words: list[str]
) -> None:
    _refused(tmp_path, text, *words)


def test_oversized_and_non_regular_annotation_files_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "field.annotations.yaml"
    with path.open("wb") as f:
        f.truncate(ANNOTATIONS_MAX_BYTES + 1)
    with pytest.raises(SourceError, match=f"{ANNOTATIONS_MAX_BYTES + 1} bytes"):
        load_annotations(path)
    path.unlink()
    path.symlink_to("/dev/zero")
    with pytest.raises(SourceError, match="annotations is not a regular file"):
        load_annotations(path)


def _frames(times: list[int]) -> list[KeyframeImages]:
    def ping(t: int, sonar: str) -> SonarPing:
        ranges = np.linspace(0.5, 4.0, 8, dtype=np.float32)
        angles = np.linspace(-0.5, 0.5, 6, dtype=np.float32)
        return SonarPing(t, sonar, np.zeros((8, 6), np.uint8), ranges, angles)

    return [
        KeyframeImages(i, t, ping(t, "horizontal"), ping(t, "vertical"))
        for i, t in enumerate(times)
    ]


def test_times_matching_no_keyframe_are_named(caplog: pytest.LogCaptureFixture) -> None:
    doc = AnnotationFile.model_validate(
        {"keyframes": [{"t_ns": t, "objects": []} for t in (10**9, 3 * 10**9, 7 * 10**9)]}
    )
    frames = _frames([10**9, 2 * 10**9, 3 * 10**9])
    with caplog.at_level(logging.WARNING):
        labelled = list(label_keyframes(frames, doc, source="f.annotations.yaml"))
    assert [f.t_ns for f in labelled] == [10**9, 3 * 10**9]
    assert "f.annotations.yaml: 1 of 3 annotated times match no keyframe" in caplog.text
    assert "t_ns 7000000000" in caplog.text
    late = AnnotationFile.model_validate({"keyframes": [{"t_ns": 10**18, "objects": []}]})
    with pytest.raises(UnmatchedAnnotations, match=r"keyframes\[\]\.t_ns: none of its 1 .*"
                       r"\(1000000000000000000\).* 3 keyframes' t_ns, 1000000000 \.\. 3000000000"):  # fmt: skip
        list(label_keyframes(frames, late, source="f.annotations.yaml"))


def test_sonarmap_train_with_unmatched_annotations_exits_2_naming_the_file(
    tmp_path: Path,
) -> None:
    from sonarmap.pipeline.training.datasets import ensure_simulation

    rec = ensure_simulation(
        ROOT / "configs/scenes/tiny.yaml", 1, tmp_path / "field.mcap", goals=1, duration_s=10.0
    )
    ann = tmp_path / "field.annotations.yaml"
    ann.write_text(HEAD + "keyframes:\n" + _entry(10**18) + _entry(10**18 + 1))
    args = ["train", str(rec), "--out", str(tmp_path / "model"), "--store", str(tmp_path / "s"),
            "--set", "train.epochs=1", "--set", "train.mc_passes=2"]  # fmt: skip
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert res.stderr.startswith(f"error: {ann}: keyframes[].t_ns: none of its 2 annotated times")
    assert "1000000000000000000, 1000000000000000001" in res.stderr
