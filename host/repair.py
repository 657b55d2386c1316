"""Rewrite a cut-short or damaged stid log into a complete one.

Everything that passes its checks (``host.mcap_scan``: every chunk's CRC) is copied
record by record into a new file with a proper summary and footer, so any MCAP tool
can open it: every channel, every message and every metadata record (``stid.hello``,
``stid.stats``, ``stid.clock``, ...). What failed its checks is left out and named.
A file that is not a stid log, or holds nothing to copy, is refused: repair never
writes an empty file and calls it done.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from mcap.writer import CompressionType, Writer

from host.hello_supply import check_source, hello_from_file
from host.mcap_log import PROFILE, SCHEMAS, TOPICS
from host.mcap_scan import holds_a_log
from host.mcap_read import REPAIR_METADATA, LogReadError, read_log, scan_log


def repair(src, dst, hello_from=None) -> dict:
    src, dst = Path(src), Path(dst)
    if dst.exists() and src.resolve() == dst.resolve():
        raise LogReadError("repair writes a new file: give an output path different from the input")
    if holds_a_log(dst):
        raise LogReadError(f"{dst} exists and is a recorded run: repair never replaces one; give another -o "
                           "path (or remove that file first)")
    if dst.exists():
        raise LogReadError(f"{dst} exists: repair does not replace a file unasked; give another -o path (or "
                           "remove that file first)")
    sc = scan_log(src)
    if not sc.messages:
        raise LogReadError(f"{src} holds no intact message (nothing to repair): "
                           + (f"{sc.lost_bytes} bytes failed their checks" if sc.damage else "it is empty"))
    log = read_log(src) if hello_from is not None else None
    if log is not None and log.hello:  # before anything is written
        raise LogReadError(f"{src} has a HELLO of its own; --hello-from is only for a log without one")
    profile = sc.header.profile if sc.header is not None else PROFILE
    library = sc.header.library if sc.header is not None else ""
    counts = {"messages": 0, "metadata": 0, "dropped_messages": 0}
    tmp = dst.with_name(dst.name + ".part")
    try:
        _write(sc, tmp, log, profile, library, hello_from, counts)
    except BaseException:
        tmp.unlink(missing_ok=True)  # a refusal or a failure leaves nothing half-written behind
        raise
    tmp.replace(dst)
    counts.update(was_truncated=sc.truncated, damage=[d.as_dict() for d in sc.damage],
                  lost_bytes=sc.lost_bytes, data_crc_ok=sc.data_crc_ok)
    return counts


def _write(sc, tmp, log, profile, library, hello_from, counts) -> None:
    with open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, enable_data_crcs=True)
        w.start(profile=profile, library=f"{library} + stid-repair".strip(" +"))
        schema_map = {0: 0}
        for sid, s in sc.schemas.items():
            schema_map[sid] = w.register_schema(s.name, s.encoding, s.data)
        channel_map = {}
        for cid, c in sc.channels.items():
            channel_map[cid] = w.register_channel(c.topic, c.message_encoding, schema_map.get(c.schema_id, 0),
                                                  c.metadata)
        for m in sc.messages:
            ch = channel_map.get(m.channel_id)
            if ch is None:  # its channel's definition was in a damaged chunk: unreadable
                counts["dropped_messages"] += 1
                continue
            w.add_message(ch, m.log_time, m.data, m.publish_time, m.sequence)
            counts["messages"] += 1
        for rec in sc.metadata:
            if rec.name == REPAIR_METADATA:
                continue  # an earlier repair's record: merged into this one below
            w.add_metadata(rec.name, rec.metadata)
            counts["metadata"] += 1
        damage = _earlier_damage(sc) + [d.as_dict() for d in sc.damage]
        if damage or sc.truncated:
            # what the original lacked stays known: the reader reports it for the repaired file too
            w.add_metadata(REPAIR_METADATA, {"damage": json.dumps(damage), "was_truncated": str(sc.truncated)})
        if hello_from is not None:
            counts["supplied"] = _supply_hello(w, log, hello_from, sc.messages, channel_map, sc.channels)
        w.finish()


def _supply_hello(w: Writer, log, hello_from, messages, channel_map, channels) -> str:
    """Write a HELLO taken from another file into a log that has none (``repair`` checked)."""
    import json

    doc, warning = hello_from_file(hello_from, log.metadata.get("stid.port"))
    hello_ch = next((channel_map[c] for c, ch in channels.items() if ch.topic == TOPICS["hello"][0]), None)
    if hello_ch is None:
        topic, schema = TOPICS["hello"]
        sid = w.register_schema(schema, "jsonschema", json.dumps(SCHEMAS[schema]).encode())
        hello_ch = w.register_channel(topic, "json", sid)
    t = min(m.log_time for m in messages)
    w.add_message(hello_ch, t, json.dumps(doc, separators=(",", ":")).encode(), t, 0)
    w.add_metadata("stid.hello", {k: (v if isinstance(v, str) else json.dumps(v)) for k, v in doc.items()})
    return warning


def _earlier_damage(sc) -> list:
    for rec in sc.metadata:
        if rec.name == REPAIR_METADATA:
            try:
                return list(json.loads(rec.metadata.get("damage", "[]")))
            except ValueError:
                return []
    return []


def repair_cli(path: str, output: str | None, hello_from: str | None = None) -> int:
    src = Path(path)
    dst = Path(output) if output else src.with_suffix(".repaired.mcap")
    if hello_from is not None:
        check_source(hello_from)
    try:
        counts = repair(src, dst, hello_from)
    except OSError as e:
        raise LogReadError(f"cannot write {dst}: {e.strerror or e}") from None
    state = "was cut short" if counts["was_truncated"] else "was already complete"
    if counts["damage"]:
        state += (f" and had {len(counts['damage'])} damaged stretch(es) ({counts['lost_bytes']} bytes) that "
                  "failed their checks and are left out")
    if counts["dropped_messages"]:
        state += f"; {counts['dropped_messages']} messages of a channel whose definition was lost are left out"
    print(f"{src} {state}; wrote {dst} with {counts['messages']} messages and {counts['metadata']} metadata "
          "records", file=sys.stderr)
    if counts.get("supplied"):
        print(f"warning: {counts['supplied']}", file=sys.stderr)
    return 0
