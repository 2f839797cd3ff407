"""Hostile YAML and config inputs: alias bombs, deep nesting, duplicate keys, huge
integers, non-regular and oversized files, through configs, `--set`, annotation files,
scene files and bag metadata (issue 34 items 3, 4, 7, 10, 11, 15).

Every case runs with `SONARMAP_CACHE_DIR` inside its work directory, so the campaign
never writes into the user's cache.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable
from pathlib import Path

from tests.contract.case import Case, names

ENV = {"SONARMAP_CACHE_DIR": "cache"}
ANN_HEAD = "format: sonarmap-annotations/1\n"
BOX = "{class_name: seawall, box_m: {x_min_m: 1, x_max_m: 2, y_min_m: -1, y_max_m: 1}}"


# -- documents -----------------------------------------------------------------------------


def laughs_block(levels: int = 9, width: int = 9) -> str:
    """Billion laughs in block style: level i is a list of `width` aliases of level i-1."""
    lines = [f"l0: &l0 [{', '.join(['lol'] * width)}]"]
    for i in range(1, levels):
        lines.append(f"l{i}: &l{i}")
        lines += [f"  - *l{i - 1}"] * width
    return "\n".join(lines) + "\n"


def laughs_flow(levels: int = 9, width: int = 9) -> str:
    """Billion laughs in one flow mapping, the bomb in a config key's value."""
    parts = [f"a0: &a0 [{', '.join(['x'] * width)}]"]
    for i in range(1, levels):
        parts.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]")
    return "{" + ", ".join(parts) + "}"


def laughs_in_value() -> str:
    """The QA's 362-byte config: the bomb is the bad value a message would print."""
    return "junk: " + laughs_flow(8, 8) + "\nkeyframes:\n  spacing_m: *a7\n"


def wide_string_alias() -> str:
    """One 64 KB string aliased 10,000 times: 640 MB if expanded."""
    return f"s: &s '{'x' * 65536}'\nkeyframes:\n  spacing_m: [{', '.join(['*s'] * 10000)}]\n"


def merge_bomb() -> str:
    """Merge keys (`<<: *a`) doubling a mapping at each level."""
    lines = ["m0: &m0 {k0: 0, k1: 1}"]
    for i in range(1, 30):
        lines.append(f"m{i}: &m{i} {{<<: [*m{i - 1}], x{i}: [*m{i - 1}, *m{i - 1}]}}")
    return "\n".join(lines) + "\n"


def alias_key() -> str:
    """An alias used as a mapping key."""
    return "k: &k keyframes\n? *k\n: {spacing_m: 7}\n"


def deep_flow(levels: int) -> str:
    return "keyframes: {spacing_m: " + "[" * levels + "]" * levels + "}\n"


def deep_flow_map(levels: int) -> str:
    return "keyframes: " + "{a: " * levels + "1" + "}" * levels + "\n"


def deep_block(levels: int) -> str:
    return "keyframes:\n" + "".join("  " * i + "- \n" for i in range(1, levels))


def deep_block_map(levels: int) -> str:
    return "".join(" " * i + "k:\n" for i in range(levels)) + " " * levels + "v: 1\n"


def annotations(entries: str) -> str:
    return ANN_HEAD + "keyframes:\n" + entries


def entry(t_ns: object, objects: str = f"[{BOX}]") -> str:
    return f"  - t_ns: {t_ns}\n    objects: {objects}\n"


def annotation_bomb() -> str:
    """The QA's 27 KB annotation bomb shape: objects lists of aliases of lists of objects."""
    lines = [ANN_HEAD + f"o0: &o0 [{', '.join([BOX] * 9)}]"]
    for i in range(1, 8):
        lines.append(f"o{i}: &o{i} [{', '.join([f'*o{i - 1}'] * 9)}]")
    return "\n".join(lines) + "\nkeyframes:\n" + entry(5, "*o7")


def annotation_committed_bomb() -> str:
    """The 9 KB one that was accepted: each keyframe's objects are one aliased long list."""
    objs = f"objs: &objs [{', '.join([BOX] * 60)}]\n"
    return ANN_HEAD + objs + "keyframes:\n" + "".join(entry(t, "*objs") for t in range(1, 80))


# -- builders ------------------------------------------------------------------------------


def config_check(text: str | bytes, name: str = "config.yaml") -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        path = work / name
        path.write_bytes(text.encode() if isinstance(text, str) else text)
        return ["config", "check", str(path)]

    return build


def config_dump(text: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        (work / "c.yaml").write_text(text)
        return ["config", "dump", "-c", "c.yaml"]

    return build


def set_value(key: str, value: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        return ["config", "dump", "--set", f"{key}={value}"]

    return build


def special_config(kind: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        path = work / "config.yaml"
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "dir":
            path.mkdir()
        elif kind == "zero-link":
            path.symlink_to("/dev/zero")
        elif kind == "sparse-50mb":
            with path.open("wb") as f:
                f.truncate(50 << 20)
        elif kind == "real-50mb":
            line = b"# " + b"c" * 1021 + b"\n"
            with path.open("wb") as f:
                for _ in range(50 * 1024):
                    f.write(line)
        elif kind == "just-over-1mb":
            path.write_bytes(b"keyframes: {spacing_m: 7}\n" + b"#" * (1 << 20))
        else:
            return ["config", "check", kind]  # a device: /dev/zero, /dev/urandom
        return ["config", "check", str(path)]

    return build


def annotated_train(text: str | None, kind: str = "text") -> Callable[[Path], list[str]]:
    """`train field.mcap` with an annotation file beside a placeholder recording: the
    annotation file is validated before the recording is read."""

    def build(work: Path) -> list[str]:
        rec = work / "field.mcap"
        rec.write_bytes(b"\x89MCAP0\r\n")
        ann = work / "field.annotations.yaml"
        if kind == "fifo":
            os.mkfifo(ann)
        elif kind == "zero-link":
            ann.symlink_to("/dev/zero")
        elif kind == "big":
            with ann.open("wb") as f:
                f.truncate(50 << 20)
        else:
            assert text is not None
            ann.write_text(text)
        return ["train", str(rec), "--out", "model", "--store", "data/store"]

    return build


def unmatched_train(times: list[int]) -> Callable[[Path], list[str]]:
    """`train` on a real small recording whose annotation times match none of its keyframes."""

    def build(work: Path) -> list[str]:
        from tests.fixtures import small_recording

        rec = small_recording(work / "field.mcap", duration_s=10.0)
        (work / "field.annotations.yaml").write_text(annotations("".join(entry(t) for t in times)))
        return ["train", str(rec), "--out", "model", "--store", "data/store",
                "--set", "train.epochs=1", "--set", "train.mc_passes=2"]  # fmt: skip

    return build


def scene(text: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        (work / "scene.yaml").write_text(text)
        return ["simulate", "-o", "out.mcap", "--scene", str(work / "scene.yaml"), "-q"]

    return build


def bag_metadata(text: str) -> Callable[[Path], list[str]]:
    def build(work: Path) -> list[str]:
        bag = work / "bag"
        bag.mkdir()
        (bag / "metadata.yaml").write_text(text)
        (bag / "bag_0.db3").write_bytes(b"")
        return ["topics", str(bag)]

    return build


# -- checks --------------------------------------------------------------------------------


def no_artifact(work: Path, done: subprocess.CompletedProcess[str]) -> str | None:
    """Nothing was committed from a refused annotation file."""
    found = list((work / "data" / "store").glob("annotations/*/annotations.json"))
    return f"committed {found[0]}" if found else None


# -- cases ---------------------------------------------------------------------------------


def _c(category: str, name: str, build: Callable[[Path], list[str]], **kw: object) -> Case:
    return Case(category, name, build, env=ENV, **kw)  # type: ignore[arg-type]


R, X, D = "resources", "exit codes", "data loss"

CASES = [
    # Alias bombs, several shapes, through every door.
    _c(R, "config: billion laughs, block style", config_check(laughs_block()), check=names("anchor &l0")),
    _c(R, "config: billion laughs, flow style", config_check(laughs_flow())),
    _c(R, "config: bomb as a bad value (the 362-byte error)", config_check(laughs_in_value())),
    _c(R, "config: 64 KB string aliased 10,000 times", config_check(wide_string_alias())),
    _c(R, "config: merge-key bomb", config_check(merge_bomb())),
    _c(R, "config: alias as a mapping key", config_check(alias_key())),
    _c(R, "config dump -c: billion laughs", config_dump(laughs_block(10, 10))),
    _c(R, "--set: billion laughs", set_value("keyframes.spacing_m", laughs_flow()),
       check=names("--set keyframes.spacing_m")),
    _c(R, "--set: flow bomb as a section", set_value("keyframes", laughs_flow())),
    _c(R, "annotations: 27 KB-shape bomb", annotated_train(annotation_bomb()), check=no_artifact),
    _c(R, "annotations: aliased object list (the 67 MB commit)", annotated_train(annotation_committed_bomb()), check=no_artifact),
    _c(R, "scene: billion laughs", scene(laughs_block())),
    _c(R, "bag metadata.yaml: billion laughs", bag_metadata(laughs_block()), check=names("metadata.yaml")),
    # Deep nesting (QA: RecursionError at 1,000 levels).
    _c(R, "config: 1,000 flow sequences", config_check(deep_flow(1000))),
    _c(R, "config: 100,000 flow sequences", config_check(deep_flow(100_000))),
    _c(R, "config: 5,000 flow mappings", config_check(deep_flow_map(5000))),
    _c(R, "config: 600 block sequences", config_check(deep_block(600)), check=names("deeper than 64")),
    _c(R, "config: 1,000 block mappings", config_check(deep_block_map(1000))),
    _c(R, "--set: 1,000 flow sequences", set_value("keyframes.spacing_m", "[" * 1000 + "]" * 1000)),
    _c(R, "--set: 25,000 flow mappings", set_value("keyframes", "{a: " * 25_000 + "1" + "}" * 25_000)),
    _c(R, "annotations: 1,000 flow sequences", annotated_train(annotations(entry(5, "[" * 1000 + "]" * 1000)))),
    _c(R, "annotations: 300 block sequences", annotated_train(ANN_HEAD + deep_block(300))),
    _c(R, "scene: 2,000 flow mappings", scene(deep_flow_map(2000))),
    # Many small values: the byte cap alone let these take 14 s; the node cap bounds them.
    _c(R, "config: 1 MB flow list of 520,000 ints", config_check("junk: [" + ",".join(["1"] * 520_000) + "]\n")),
    _c(R, "config: 1 MB of 100,000 one-letter mappings", config_check("".join(f"k{i}: {{a: 1}}\n" for i in range(90_000)))),
    _c(R, "annotations: 4 MB flow list of 2,000,000 ints", annotated_train(ANN_HEAD + "keyframes: [" + ",".join(["1"] * 2_000_000) + "]\n")),
    _c(R, "annotations: 60,000 empty keyframes", annotated_train(annotations("".join(f"  - {{t_ns: {t}}}\n" for t in range(60_000))))),
    # Huge integers (QA: ValueError traceback past 4,300 digits).
    _c(R, "config: 5,000-digit int", config_check("keyframes:\n  spacing_m: " + "9" * 5000 + "\n"), check=names("line 2:14")),
    _c(R, "config: 1,000,000-digit int", config_check("keyframes:\n  spacing_m: " + "9" * 1_000_000 + "\n")),
    _c(R, "config: 5,000-digit hex int", config_check("keyframes:\n  spacing_m: 0x" + "f" * 5000 + "\n")),
    _c(R, "config: 3,000-part sexagesimal int", config_check("keyframes:\n  spacing_m: " + "59:" * 3000 + "1\n")),
    _c(R, "config: 5,000-digit int with underscores", config_check("train:\n  epochs: " + "9_" * 5000 + "9\n")),
    _c(R, "--set: 5,000-digit int", set_value("train.epochs", "9" * 5000)),
    _c(R, "--set: 10,000-digit ints in a list", set_value("keyframes.spacing_m", ",".join(["9" * 10_000] * 3))),
    _c(R, "scene: 5,000-digit seed-like int", scene("name: x\nobjects: []\nsize: " + "9" * 5000 + "\n")),
    # Files that are not small regular files.
    _c(R, "config check /dev/zero", special_config("/dev/zero"), check=names("/dev/zero", "not a regular file")),
    _c(R, "config check /dev/urandom", special_config("/dev/urandom")),
    _c(R, "config is a FIFO nobody writes", special_config("fifo")),
    _c(R, "config is a symlink to /dev/zero", special_config("zero-link")),
    _c(R, "config is a directory", special_config("dir")),
    _c(R, "config: 50 MB sparse", special_config("sparse-50mb")),
    _c(R, "config: 50 MB of comments", special_config("real-50mb")),
    _c(R, "config: 1 MB + 26 bytes", special_config("just-over-1mb")),
    _c(R, "annotations: FIFO", annotated_train(None, "fifo")),
    _c(R, "annotations: symlink to /dev/zero", annotated_train(None, "zero-link")),
    _c(R, "annotations: 50 MB", annotated_train(None, "big")),
    # One argument is at most 128 KB (Linux MAX_ARG_STRLEN): the largest --set a shell passes.
    _c(R, "--set: 120 KB value", set_value("keyframes.spacing_m", "7" * 120_000)),
    # Exit codes and messages.
    _c(X, "annotations: t_ns = 2**63", annotated_train(annotations(entry(2**63))), check=names("keyframes[0].t_ns", "annotations.yaml")),
    _c(X, "annotations: t_ns = 2**64 + 1", annotated_train(annotations(entry(2**64 + 1))), check=names("keyframes[0].t_ns")),
    _c(X, "annotations: t_ns = -1", annotated_train(annotations(entry(-1))), check=names("keyframes[0].t_ns")),
    _c(X, "annotations: t_ns of 5,000 digits", annotated_train(annotations(entry("9" * 5000))), check=names("annotations.yaml", "line 3:")),
    _c(X, "annotations: t_ns 1e30 (a float)", annotated_train(annotations(entry("1e30"))), check=names("keyframes[0].t_ns")),
    _c(X, "annotations: times matching no keyframe", unmatched_train([10**18, 10**18 + 5]),
       check=names("annotations.yaml", "t_ns", "1000000000000000000"), max_seconds=60.0),
    _c(X, "annotations: 300 KB class name", annotated_train(annotations(entry(5, "[{class_name: '" + "q" * 300_000 + "'}]"))), check=names("class_name")),
    _c(X, "config: 300 KB string for a float", config_check("keyframes:\n  spacing_m: '" + "z" * 300_000 + "'\n"), check=names("keyframes.spacing_m")),
    _c(X, "config: 100,000-item list for a float", config_check("keyframes:\n  spacing_m: [" + ", ".join(["1"] * 100_000) + "]\n")),
    _c(X, "config: 1e400 for a float", config_check("keyframes:\n  spacing_m: 1e400\n"), check=names("keyframes.spacing_m")),
    _c(X, "config: newline in the file name", config_check("a: 1\na: 2\n", "two\nlines.yaml"), check=names("two\\nlines.yaml")),
    _c(X, "--set: newline in the value", set_value("keyframes.spacing_m", '"abc\\ndef"'), check=names("--set keyframes.spacing_m")),
    _c(X, "--set: 120 KB unknown key", set_value("keyframes." + "k" * 120_000, "1")),
    _c(X, "config: 300 KB unknown key", config_check("keyframes:\n  " + "k" * 300_000 + ": 1\n")),
    _c(X, "config: not UTF-8", config_check(b"keyframes: {spacing_m: \xff\xfe}\n")),
    _c(X, "config: tab-indented", config_check("keyframes:\n\tspacing_m: 7\n")),
    # Duplicate keys: the last one silently winning loses the first one's values.
    _c(D, "config: second keyframes: block", config_check("keyframes:\n  spacing_m: 7\nfeatures: {}\nkeyframes:\n  angle_deg: 10\n"),
       check=names("duplicate key 'keyframes'", "line 4:1")),
    _c(D, "config: field given twice", config_check("keyframes:\n  spacing_m: 7\n  spacing_m: 3\n"), check=names("duplicate key 'spacing_m'")),
    _c(D, "config: field twice in a flow mapping", config_check("keyframes: {spacing_m: 7, spacing_m: 3}\n"), check=names("duplicate key")),
    _c(D, "config: quoted and plain spellings", config_check("keyframes:\n  spacing_m: 7\n  'spacing_m': 3\n"), check=names("duplicate key")),
    _c(D, "config: duplicate in a list's mapping", config_check("training:\n  sets:\n    - {scene: harbour, seed: 1, seed: 2, goals: 3}\n"), check=names("duplicate key 'seed'")),
    _c(D, "config dump -c: duplicate section", config_dump("train: {epochs: 3}\ntrain: {mc_passes: 2}\n"), check=names("duplicate key 'train'")),
    _c(D, "--set: duplicate key in a flow mapping", set_value("keyframes", "{spacing_m: 7, spacing_m: 3}"), check=names("--set keyframes", "duplicate key")),
    _c(D, "annotations: second keyframes: list", annotated_train(annotations(entry(5)) + "keyframes:\n" + entry(6)), check=no_artifact),
    _c(D, "annotations: t_ns twice in an entry", annotated_train(annotations("  - t_ns: 5\n    t_ns: 6\n    objects: []\n")), check=names("duplicate key 't_ns'")),
    _c(D, "annotations: box_m twice in an object", annotated_train(annotations(entry(5, "[{class_name: seawall, box_m: {x_min_m: 1, x_max_m: 2, y_min_m: -1, y_max_m: 1}, box_m: {x_min_m: 3, x_max_m: 4, y_min_m: -1, y_max_m: 1}}]"))),
       check=names("duplicate key 'box_m'")),
    _c(D, "annotations: JSON with keyframes twice", annotated_train('{"format": "sonarmap-annotations/1", "keyframes": [{"t_ns": 5}], "keyframes": [{"t_ns": 6}]}'),
       check=names("duplicate key 'keyframes'")),
    _c(D, "annotations: int keys 1 and 0x1", annotated_train(ANN_HEAD + "extra: {1: a, 0x1: b}\nkeyframes:\n" + entry(5)), check=names("duplicate key 1")),
    _c(D, "scene: objects twice", scene("name: x\nobjects: []\nobjects: []\n"), check=names("duplicate key 'objects'")),
    _c(D, "bag metadata.yaml: duplicate key", bag_metadata("rosbag2_bagfile_information: {}\nrosbag2_bagfile_information: {}\n"), check=names("duplicate key")),
]  # fmt: skip
