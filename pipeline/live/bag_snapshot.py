"""A growing rosbag2 directory (MCAP storage): each split file a `McapSnapshot`, and the
bag closed once its recorder has stopped."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from sonarmap.pipeline.engine.errors import SourceError
from sonarmap.pipeline.live.growing import Growth, McapSnapshot, check_followable, mcap_closed

__all__ = ["SETTLE_S", "BagSnapshot"]

SETTLE_S = 2.0
"""How long a bag must look finished, with no new file, record or metadata, before it is
taken as closed: a recorder that writes `metadata.yaml` at each split opens its next
file right after (at the first split the metadata names only the closed first file)."""


class BagSnapshot:
    """Keeps `folder` a rosbag2 directory (MCAP storage) of `source`'s complete records.

    A recorder writing a bag directory (`ros2 bag record -s mcap`) opens its split files
    one after the other and writes `metadata.yaml` when it stops. Each split file found
    gets its own `McapSnapshot`; the snapshot's own `metadata.yaml` lists those holding
    something. The bag is closed when its `metadata.yaml` is there, every file it names is
    closed, every other MCAP file of the directory is closed too (one still written is the
    next split), and that held for `SETTLE_S` with nothing new.

    Args:
        source: the bag directory being written.
        folder: where the snapshot directory is made (its name is `source`'s).
    """

    def __init__(
        self, source: Path, folder: Path, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.source = Path(source)
        self.path = Path(folder) / (self.source.name or "bag")
        self.path.mkdir(parents=True, exist_ok=True)
        self._files: dict[str, McapSnapshot] = {}
        self._listed: list[str] = []
        self._clock = clock
        self._done_since: tuple[object, float] | None = None  # (what was seen, since when)
        self.waiting = ""
        """Why a bag whose metadata is written is not closed yet ("" when nothing to say)."""

    @property
    def size(self) -> int:
        """Bytes of the source's files copied into the snapshot."""
        return sum(s.size for s in self._files.values())

    def update(self) -> Growth:
        """Copy the complete records added to the bag's files since the last call."""
        check_followable(self.source)
        names = sorted((p.name for p in self.source.glob("*.mcap")), key=_split_order)
        new_bytes = records = 0
        for name in names:
            snap = self._files.setdefault(name, McapSnapshot(self.source / name, self.path / name))
            if snap.data_ended:
                continue
            growth = snap.update()
            new_bytes, records = new_bytes + growth.new_bytes, records + growth.records
        listed = [n for n in names if self._files[n].size > 0]
        if listed != self._listed:
            self._write_metadata(listed)
        times = [s.last_log_time_ns for s in self._files.values() if s.last_log_time_ns]
        return Growth(new_bytes, records, max(times, default=None), self._closed(names))

    def _write_metadata(self, names: list[str]) -> None:
        import yaml

        doc = {
            "rosbag2_bagfile_information": {
                "storage_identifier": "mcap",
                "relative_file_paths": names,  # no topic counts: they are not known yet
            }
        }
        tmp = self.path / "metadata.yaml.tmp"
        tmp.write_text(yaml.safe_dump(doc))
        tmp.replace(self.path / "metadata.yaml")
        self._listed = names

    def _closed(self, names: list[str]) -> bool:
        """The bag is done when its metadata lists only closed files, every file of the
        directory is listed or closed, and that held, with nothing new, for `SETTLE_S`:
        a recorder may write `metadata.yaml` at each split, before its next file."""
        self.waiting = ""
        meta = self.source / "metadata.yaml"
        if not meta.is_file() or not names:
            return False
        from sonarmap.pipeline.engine.config.yaml_files import read_yaml

        try:
            info = read_yaml(meta, "bag metadata", SourceError)["rosbag2_bagfile_information"]
            listed = sorted(Path(n).name for n in info["relative_file_paths"])
        except (SourceError, KeyError, TypeError):
            return False  # being written, or not yet the final one: look again
        closed = {n for n in names if self._files[n].data_ended and mcap_closed(self.source / n)}
        if missing := sorted(set(listed) - set(names)):
            if len(closed) == len(names):  # the recorder is done: the file will not come
                raise SourceError(
                    f"{meta}: lists {missing[0]}, which is not in {self.source} "
                    f"({len(missing)} of {len(listed)} listed files missing)"
                )
            return False
        if unclosed := [n for n in listed if n not in closed]:
            self.waiting = f"{meta} lists every file, but {unclosed[0]} has no MCAP footer yet"
            return False
        # A file the metadata does not list that is still being written is the next split;
        # a closed one is not the bag's (`run` does not read it either).
        if any(n not in listed and n not in closed for n in names):
            return False
        seen = (tuple(names), tuple(listed), meta.stat().st_mtime_ns, self.size)
        now = self._clock()
        if self._done_since is None or self._done_since[0] != seen:
            self._done_since = (seen, now)
        return now - self._done_since[1] >= SETTLE_S


def _split_order(name: str) -> tuple[int, str]:
    """rosbag2 names its split files `BAG_0.mcap`, `BAG_1.mcap`, ... `BAG_10.mcap`."""
    stem = name.rsplit(".", 1)[0]
    index = stem.rsplit("_", 1)[-1]
    return (int(index) if index.isdigit() else -1, name)
