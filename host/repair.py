"""Rewrite a cut-short MCAP file (logger killed, power lost) into a complete one.

Everything up to the last complete chunk is copied record by record into a new
file with a proper summary and footer, so any MCAP tool can open it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from host.mcap_read import LogReadError, iter_records


def repair(src, dst) -> dict:
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise LogReadError("repair writes a new file: give an output path different from the input")
    counts = {"messages": 0, "metadata": 0}
    with open(dst, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="stid", library="stid-repair")
        schema_map, channel_map = {0: 0}, {}
        gen = iter_records(src)
        truncated = False
        try:
            while True:
                rec = next(gen)
                if isinstance(rec, Schema) and rec.id not in schema_map:
                    schema_map[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, Channel) and rec.id not in channel_map:
                    channel_map[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                             schema_map.get(rec.schema_id, 0), rec.metadata)
                elif isinstance(rec, Message) and rec.channel_id in channel_map:
                    w.add_message(channel_map[rec.channel_id], rec.log_time, rec.data, rec.publish_time,
                                  rec.sequence)
                    counts["messages"] += 1
                elif isinstance(rec, Metadata):
                    w.add_metadata(rec.name, rec.metadata)
                    counts["metadata"] += 1
        except StopIteration as stop:
            truncated = bool(stop.value)
        w.finish()
    counts["was_truncated"] = truncated
    return counts


def repair_cli(path: str, output: str | None) -> int:
    src = Path(path)
    if not src.exists():
        raise LogReadError(f"{src} does not exist")
    dst = Path(output) if output else src.with_suffix(".repaired.mcap")
    counts = repair(src, dst)
    state = "was cut short" if counts["was_truncated"] else "was already complete"
    print(f"{src} {state}; wrote {dst} with {counts['messages']} messages", file=sys.stderr)
    return 0
