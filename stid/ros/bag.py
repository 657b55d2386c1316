"""Open a ROS bag with ``rosbags`` (it reads ROS 1 bags and ROS 2 bags in MCAP or
SQLite storage, offline, from the message definitions the bag carries) and hand out
the fields of the topics asked for.

Which kind a file is, is decided by its content: a stid-log MCAP and a ROS 2 MCAP share
the magic, and only the ROS 2 one has the ``ros2`` profile and CDR channels.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stid.errors import InputError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class Topic:
    name: str
    msgtype: str  # ROS 2 spelling: sensor_msgs/msg/Imu (rosbags gives ROS 1 types so too)
    count: int

    def describe(self) -> str:
        return f"{self.name} ({self.msgtype}, {self.count} messages)"


def kind_of(path) -> str | None:
    """``"ros1"``, ``"ros2"`` (a bag directory, an MCAP of the ROS 2 profile, or a ROS 2
    SQLite file) or None (not a ROS bag: a stid-log MCAP, a CSV, ...)."""
    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        # rosbag2 writes metadata.yaml when it stops: a killed recorder's directory has its .mcap
        # files alone (one, or the pieces of a split bag)
        inside = split_files(path)
        return "ros2" if inside and all(kind_of(f) == "ros2" for f in inside) else None
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    if head.startswith(SQLITE_MAGIC):
        return "ros2"
    if head.startswith(MCAP_MAGIC):
        return "ros2" if _mcap_is_ros2(path) else None
    return None


def split_files(bag_dir) -> list:
    """The .mcap files of a ROS 2 bag directory in the order rosbag2 wrote them (NAME_0.mcap,
    NAME_1.mcap, ..., NAME_10.mcap: by the number, not as text)."""
    import re

    def key(f):
        m = re.search(r"_(\d+)$", f.stem)
        return (f.stem[:m.start()] if m else f.stem, int(m.group(1)) if m else -1)

    return sorted(Path(bag_dir).glob("*.mcap"), key=key)


ROS2_SCHEMAS = ("ros2msg", "ros2idl")


def _mcap_is_ros2(path) -> bool:
    """The MCAP header's profile (the first record after the magic): ``ros2`` for rosbag2,
    ``stid`` for stid-log; a writer that leaves the profile empty is told by its schemas
    (``ros2msg``, ``ros2idl``). A file whose header does not parse is left to the stid-log
    reader, which says what is damaged."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            profile = reader.get_header().profile
            if profile:
                return profile == "ros2"
            summary = reader.get_summary()
            return summary is not None and any(s.encoding in ROS2_SCHEMAS for s in summary.schemas.values())
    except (McapError, OSError, ValueError, EOFError, UnicodeDecodeError):
        return False


class Bag:
    """An open ROS bag. Use as a context manager."""

    def __init__(self, path, pieces=None):
        """``pieces``: the files of a split bag read without its metadata.yaml (``path`` is then its
        directory, for messages), in order."""
        self.path = Path(path)
        self.pieces = [Path(p) for p in pieces] if pieces else None
        self.kind = kind_of(self.path)
        if self.kind is None:
            raise InputError(f"{self.path} is not a ROS bag")
        want = ".bag" if self.kind == "ros1" else (".mcap", ".db3")
        if not self.path.is_dir() and self.path.suffix.lower() not in (want if isinstance(want, tuple) else (want,)):
            # rosbags picks the format by the name; say so rather than misread it
            name = want if isinstance(want, str) else " or ".join(want)
            raise InputError(f"{self.path} holds a {'ROS 1' if self.kind == 'ros1' else 'ROS 2'} bag but is not "
                             f"named {name}: rename it so")
        if not self.path.is_dir() and self.kind == "ros2" and messages_compressed(self.path.parent):
            raise InputError(f"{self.path}: each message in it is compressed on its own (the metadata.yaml beside it "
                             f"says so, and only it): give the bag's directory, {self.path.parent}")
        self._reader = None

    def __enter__(self) -> "Bag":
        from rosbags.highlevel import AnyReader, AnyReaderError

        from stid.ros.message_types import default_typestore

        try:
            try:
                reader = AnyReader(self.pieces or [self.path])
                reader.open()
            except AnyReaderError as e:
                if "no type definitions" not in str(e):
                    raise
                # (the standard types are loaded only then: importing them costs half a second)
                reader = AnyReader(self.pieces or [self.path], default_typestore=default_typestore(self.kind))
                reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags' errors for a damaged or cut-short bag
            raise InputError(f"{self.path} is a {self.label} that does not open: {_first_line(e)}"
                             f"{_remedy(self.kind, str(e))}") from None
        self._reader = reader
        self.topics = {}
        for c in reader.connections:
            t = self.topics.get(c.topic)
            if t is None:
                self.topics[c.topic] = Topic(c.topic, c.msgtype, c.msgcount)
            else:  # a ROS 1 topic with several publishers has one connection each
                t.count += c.msgcount
        return self

    def __exit__(self, *exc) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    @property
    def label(self) -> str:
        return {"ros1": "ROS 1 bag", "ros2": "ROS 2 bag"}[self.kind]

    def listing(self) -> str:
        """The topics, for messages: ``/imu (sensor_msgs/msg/Imu, 12000 messages), ...``."""
        if not self.topics:
            return "no topics"
        return ", ".join(t.describe() for t in sorted(self.topics.values(), key=lambda t: t.name))

    def read(self, wanted: dict) -> dict:
        """``{topic: {"t_log": ns array, field: array, ...}}`` for ``wanted``: ``{topic: [field, ...]}``.
        Log times are the bag's receive times [ns]; messages in the order of those."""
        from stid.ros.columns import read_fields

        got = self._fast(wanted) or self._by_rosbags(wanted)
        out = {}
        for name, fields in wanted.items():
            t_log, blocks = got[name]
            order = np.argsort(t_log, kind="stable")
            order = None if np.all(order[1:] > order[:-1]) else order  # (file order is time order, as a rule)
            cols = read_fields(blocks, self._reader.typestore, self.topics[name].msgtype, list(fields),
                               self.kind == "ros2", name, order)
            cols["t_log"] = t_log if order is None else t_log[order]
            out[name] = cols
        return out

    def _fast(self, wanted):
        """ROS 2 MCAP storage in one file: stid.ros.mcap_blocks (none for anything else)."""
        files = self.pieces or (sorted(self.path.glob("*.mcap")) if self.path.is_dir() else [self.path])
        if self.kind != "ros2" or len(files) != 1 or files[0].suffix.lower() != ".mcap":
            return None
        if messages_compressed(files[0].parent):
            # each message compressed on its own (rosbag2's --compression-mode message): rosbags undoes
            # it; the block reader would read compressed bytes as the message (a new user's bag was
            # called damaged)
            return None
        from stid.ros.mcap_blocks import read_topics

        return read_topics(files[0], wanted)

    def _by_rosbags(self, wanted):
        from stid.ros.columns import as_rows

        reader = self._reader
        conns = [c for c in reader.connections if c.topic in wanted]
        raws = {t: [] for t in wanted}
        times = {t: [] for t in wanted}
        try:
            for c, t_ns, raw in reader.messages(connections=conns):
                raws[c.topic].append(raw)
                times[c.topic].append(t_ns)
        except Exception as e:  # noqa: BLE001 - rosbags raises its own errors for a damaged bag
            raise InputError(f"{self.path}: the bag is damaged and could not be read to its end "
                             f"({_first_line(e)})") from None
        return {t: (np.asarray(times[t], np.int64), as_rows(raws[t])) for t in wanted}


def _first_line(e: Exception) -> str:
    text = str(e).strip() or type(e).__name__
    return text.splitlines()[0]


def _remedy(kind: str, error: str) -> str:
    """What rebuilds a bag a recorder did not close (killed, or the disk full): its end or index
    is missing, the messages before it are there. Empty for other damage."""
    text = error.lower()
    if kind == "ros1" and ("index" in text or "header could not be read" in text):
        return (" (a recording that was not closed: `rosbag reindex` rebuilds its index, and the bag then "
                "reads up to where it stopped)")
    if kind == "ros2" and ("magic" in text or "footer" in text or "summary" in text):
        return (" (a recording that was not closed: its end is missing; `mcap recover FILE -o FIXED.mcap`, the "
                "mcap command-line tool, rewrites it with what is there)")
    return ""


def messages_compressed(bag_dir: Path) -> bool:
    """rosbag2's metadata.yaml in ``bag_dir`` says each message is compressed on its own."""
    meta = bag_dir / "metadata.yaml"
    return meta.is_file() and re.search(r"compression_mode:\s*['\"]?message", meta.read_text(errors="replace")) is not None
