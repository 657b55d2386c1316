"""A ROS 2 bag without its end, made readable: one that ``ros2 bag record`` is still writing
(stid live), or whose recorder was killed or ran out of disk (stid fit and the rest).

rosbag2 (MCAP storage) writes ``BAG/BAG_0.mcap`` chunk by chunk and the bag's
``metadata.yaml`` and the file's summary and end only when it stops: until then neither
rosbags nor stid's loader opens it ("File end magic is invalid"). Every complete chunk
is intact, though: the mcap library's non-seeking reader yields their messages and
stops at the cut (HARDWARE.md, MCAP). They are written to a finished MCAP file of the
same profile in a scratch directory, which the loader reads as any ROS 2 bag.
"""

from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"


def being_recorded(path: Path) -> Path | None:
    """The MCAP file of a ROS 2 bag without its end (still being written, or never closed), or
    None (finished, or not a ROS 2 MCAP bag)."""
    from stid.ros.bag import kind_of

    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return None
        files = sorted(path.glob("*.mcap"))
        if len(files) != 1:
            return None
        path = files[0]
    elif path.suffix.lower() != ".mcap":
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
            size = f.seek(0, 2)
            f.seek(max(size - len(MAGIC), 0))
            tail = f.read(len(MAGIC))
    except OSError:
        return None
    if head != MAGIC or (tail == MAGIC and size > 2 * len(MAGIC)):
        return None
    return path if kind_of(path) == "ros2" else None


def readable_copy(src: Path, dst: Path) -> int:
    """Every message of the complete chunks of ``src`` into a finished MCAP file ``dst``
    (same profile, schemas and channels); the number of messages."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader
    from mcap.writer import CompressionType, Writer

    n = 0
    tmp = dst.with_name(dst.name + ".part")
    with open(src, "rb") as f, open(tmp, "wb") as out:
        reader = NonSeekingReader(f)
        w = Writer(out, compression=CompressionType.NONE)
        w.start(profile="ros2", library="stid live")  # (being_recorded found the ros2 profile)
        schemas, channels = {}, {}
        try:
            for schema, channel, msg in reader.iter_messages(log_time_order=False):
                if schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                if channel.id not in channels:
                    channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                              schemas[schema.id], channel.metadata)
                w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
                n += 1
        except (McapError, EOFError, ValueError, OSError, struct.error):
            pass  # the cut (a record half written): everything before it is in
        w.finish()
    tmp.replace(dst)
    return n
