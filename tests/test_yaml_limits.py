"""The bounded YAML loader (issue 34 items 3, 4, 7, 10, 11): every YAML sonarmap reads.

Hostile configs, `--set` values and files go in through the CLI (`config check`,
`config dump --set`) and must be refused with exit 2 and one short `error:` line naming
the file (or `--set KEY`) and the line:column, before anything large is built.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from sonarmap.pipeline.cli import app
from sonarmap.pipeline.engine.config.load import load_config
from sonarmap.pipeline.engine.config.validation import short
from sonarmap.pipeline.engine.config.yaml_files import CONFIG_MAX_BYTES, MAX_DEPTH, load_yaml_text
from sonarmap.pipeline.engine.errors import ConfigError
from sonarmap.pipeline.graph import all_stages, extra_sections

runner = CliRunner()

MAX_LINE = 400
"""The longest one-line error the contract allows (as `tests/contract/case.py`)."""

BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8)
)
"""The billion-laughs shape: 9**9 strings from a few hundred bytes if aliases expanded."""


def _refused(args: list[str], *words: str) -> str:
    res = runner.invoke(app, args)
    assert res.exit_code == 2, (res.exit_code, res.output[:500])
    err = res.stderr
    assert err.count("\n") == 1 and err.startswith("error: "), err[:500]
    assert len(err) <= MAX_LINE and "Traceback" not in err, err[:500]
    for word in words:
        assert word in err, err
    return err


@pytest.mark.parametrize(
    ("text", "words"),
    [
        # QA: a second `keyframes:` block silently dropped the first one's spacing_m.
        ("keyframes:\n  spacing_m: 7\nkeyframes:\n  angle_deg: 10\n",
         ["line 3:1", "duplicate key 'keyframes'", "first at line 1:1"]),
        ("keyframes:\n  spacing_m: 7\n  spacing_m: 3\n", ["line 3:3", "duplicate key 'spacing_m'"]),
        ("{keyframes: {spacing_m: 7, spacing_m: 3}}", ["duplicate key 'spacing_m'"]),
        (BOMB, ["line 1:4", "anchor &a refused"]),
        ("keyframes: *x\n", ["line 1:12"]),
        ("x: " + "[" * 2000 + "]" * 2000 + "\n", ["line 1:"]),
        ("x:\n" + "".join("  " * i + "- \n" for i in range(1, 200)), [f"deeper than {MAX_DEPTH}"]),
        ("keyframes:\n  spacing_m: " + "9" * 5000 + "\n", ["line 2:14", "integer of 5000 characters"]),
    ],
    ids=["dup-section", "dup-field", "dup-flow", "alias-bomb", "unknown-alias", "deep-flow",
         "deep-block", "huge-int"],
)  # fmt: skip
def test_a_hostile_config_is_one_short_line_naming_file_and_place(
    tmp_path: Path, text: str, words: list[str]
) -> None:
    path = tmp_path / "hostile.yaml"
    path.write_text(text)
    err = _refused(["config", "check", str(path)], str(path), *words)
    assert "9999999999999999999999" not in err  # a short prefix of the value at most


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("&a [1, 2]", ["--set keyframes.spacing_m", "anchor &a refused"]),
        ("{a: 1, a: 2}", ["--set keyframes.spacing_m", "duplicate key 'a'"]),
        ("[" * 1000 + "]" * 1000, ["--set keyframes.spacing_m"]),
        ("9" * 5000, ["--set keyframes.spacing_m", "integer of 5000 characters"]),
        ("x" * 100_000, ["--set keyframes.spacing_m", "100000 characters"]),
        ('"abc\\ndef"', ["--set keyframes.spacing_m", "'abc\\ndef'"]),
    ],
    ids=["anchor", "dup", "deep", "huge-int", "huge-text", "newline"],
)
def test_a_hostile_set_value_names_the_key(value: str, words: list[str]) -> None:
    _refused(["config", "dump", "--set", f"keyframes.spacing_m={value}"], *words)


def test_a_long_bad_value_is_quoted_by_a_short_prefix(tmp_path: Path) -> None:
    path = tmp_path / "long.yaml"
    path.write_text("keyframes:\n  spacing_m: '" + "z" * 300_000 + "'\n")
    err = _refused(["config", "check", str(path)], "keyframes.spacing_m = 'zzz")
    assert err.count("z") < 80
    # A huge list is counted, not printed; a huge integer by its size.
    assert short(list(range(10**5))) == "[0, 1, 2, 3, 4, 5, ...]"
    assert len(short(["z" * 10**6] * 50)) <= 60
    assert short(10**4000).startswith("<integer of")


def test_a_newline_in_a_path_does_not_split_the_line(tmp_path: Path) -> None:
    path = tmp_path / "two\nlines.yaml"
    path.write_text("a: 1\na: 2\n")
    _refused(["config", "check", str(path)], "two\\nlines.yaml", "duplicate key 'a'")


def test_non_regular_and_oversized_files_are_refused_before_reading(tmp_path: Path) -> None:
    _refused(["config", "check", "/dev/zero"], "/dev/zero: config is not a regular file")
    fifo = tmp_path / "config.fifo"
    os.mkfifo(fifo)  # nobody writes: opening it for reading would block forever
    _refused(["config", "check", str(fifo)], "is not a regular file")
    _refused(["config", "check", str(tmp_path)], "is not a regular file")
    big = tmp_path / "big.yaml"
    with big.open("wb") as f:
        f.truncate(CONFIG_MAX_BYTES + 1)  # sparse: the size alone refuses it
    _refused(["config", "check", str(big)], f"{CONFIG_MAX_BYTES + 1} bytes")


def test_a_document_of_too_many_values_is_refused_while_composing() -> None:
    text = "[" + ", ".join(["1"] * 11) + "]"
    assert len(load_yaml_text(text, "x", "v", ConfigError, max_nodes=12)) == 11
    with pytest.raises(ConfigError, match=r"^x: v refused \(line 1:\d+: more than 11 values"):
        load_yaml_text(text, "x", "v", ConfigError, max_nodes=11)


def test_valid_yaml_still_loads_and_a_set_overrides_the_file(tmp_path: Path) -> None:
    path = tmp_path / "ok.yaml"
    path.write_text("keyframes: {spacing_m: 7}\n# a comment\nfeatures: {}\n")
    # A --set overrides the file; two --set of one key are refused, as a duplicate key in
    # a document is (the first would silently go).
    cfg = load_config(all_stages(), path, ["keyframes.spacing_m=4"], extra_sections())
    assert cfg.keyframes.spacing_m == 4  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match="spacing_m: given twice"):
        load_config(
            all_stages(), path, ["keyframes.spacing_m=3", "keyframes.spacing_m=4"],
            extra_sections(),
        )  # fmt: skip
    refined = ["keyframes={spacing_m: 5}", "keyframes.rotation_deg=10"]  # a section, refined
    cfg = load_config(all_stages(), path, refined, extra_sections())
    assert (cfg.keyframes.spacing_m, cfg.keyframes.rotation_deg) == (5, 10)  # type: ignore[attr-defined]
    assert load_yaml_text("t: 9223372036854775807\n", "x", "v", ConfigError) == {"t": 2**63 - 1}
    with pytest.raises(ConfigError, match=r"^x: v is not valid YAML \(line \d+:\d+: "):
        load_yaml_text("a: [1, 2\n", "x", "v", ConfigError)
