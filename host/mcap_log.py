"""The MCAP file of a logged run: what goes in it and how it stays safe.

Channels (all messages carry the host receive time as log_time, ns since epoch):

| topic | encoding | content |
|---|---|---|
| `/stid/raw` | `stid.raw` (no schema) | every byte read from the port, as read: a decoder bug can be fixed later |
| `/stid/frames` | `stid.frames.v1` (no schema) | the accepted frames of one port read, each as u16 length + frame without COBS and CRC; the fast path for loading |
| `/stid/samples` | `json` + jsonschema | the samples of one port read as column arrays: raw counts, index, unwrapped MCU time and host time (in Foxglove plot e.g. `/stid/samples.ay[0]`) |
| `/stid/status` | `json` + jsonschema | the firmware's STATUS frames |
| `/stid/hello` | `json` + jsonschema | the firmware's HELLO frames |
| `/stid/events` | `json` + jsonschema | connect, disconnect, reconnect, firmware restart |
| `/stid/stats` | `json` + jsonschema | link statistics, every second and at the end |

Metadata records: `stid.hello` (first HELLO of each boot), `stid.clock` (offset and
drift of MCU time against host time) and `stid.stats` (final link statistics).

Crash safety: ``flush()`` closes the open chunk and writes it out at least once
per second (``Writer.flush``, mcap >= 1.6) and fsyncs, so a SIGKILL or a power cut
loses at most about a second. A file cut short is still readable up to its last
complete chunk, and ``host.repair`` rewrites it into a complete one.
"""

from __future__ import annotations

import json
import os
import time

from mcap.writer import CompressionType, Writer

SCHEMAS = {
    "stid.Samples": {
        "type": "object",
        "description": "The samples of one port read as column arrays: raw ADC counts "
                       "(65535 = not sampled; convert with the HELLO content), sample index, unwrapped "
                       "MCU time [us] and the clock model's host time [ns]. steer_t_us: MCU ticks of the "
                       "falling edge of the servo pulse whose width is steer_us (4294967295: unknown, "
                       "protocol 1). wheelK_*: hall sensors 1-3 of four-wheel frames (present only then).",
        "properties": {
            "boot": {"type": "string"}, "n": {"type": "integer"},
            **{k: {"type": "array", "items": {"type": "integer"}}
               for k in ("index", "t_mcu_us", "t_host_ns", "ax", "ay", "az", "yaw", "steer_us", "wheel_count",
                         "wheel_t_us", "vbat", "steer_t_us", "wheel1_count", "wheel1_t_us", "wheel2_count",
                         "wheel2_t_us", "wheel3_count", "wheel3_t_us")},
        },
    },
    "stid.Status": {"type": "object", "description": "Firmware STATUS frame", "properties": {}},
    "stid.Hello": {"type": "object", "description": "Firmware HELLO frame", "properties": {}},
    "stid.Event": {"type": "object", "properties": {"event": {"type": "string"}, "detail": {"type": "string"}}},
    "stid.Stats": {"type": "object", "description": "Link statistics", "properties": {}},
}
TOPICS = {
    "samples": ("/stid/samples", "stid.Samples"),
    "status": ("/stid/status", "stid.Status"),
    "hello": ("/stid/hello", "stid.Hello"),
    "events": ("/stid/events", "stid.Event"),
    "stats": ("/stid/stats", "stid.Stats"),
}
RAW_TOPIC = "/stid/raw"
FRAMES_TOPIC = "/stid/frames"
FRAME_ENCODING = "stid.frames.v1"
PROFILE = "stid"


class McapLog:
    """Write a run. Every write goes to the open chunk; ``flush`` makes it durable."""

    def __init__(self, path, fsync: bool = True):
        self.path = str(path)
        self._f = open(self.path, "wb")
        self._fsync = fsync
        self._w = Writer(self._f, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
        self._w.start(profile=PROFILE, library="stid-log")
        self._ch = {}
        self._seq = {}
        for key, (topic, schema) in TOPICS.items():
            sid = self._w.register_schema(schema, "jsonschema", json.dumps(SCHEMAS[schema]).encode())
            self._ch[key] = self._w.register_channel(topic, "json", sid)
        self._ch["raw"] = self._w.register_channel(RAW_TOPIC, "stid.raw", 0)
        self._ch["frames"] = self._w.register_channel(FRAMES_TOPIC, FRAME_ENCODING, 0)
        for key in self._ch:
            self._seq[key] = 0
        self._last_flush = time.monotonic()
        self.closed = False

    def _add(self, key: str, data: bytes, log_ns: int) -> None:
        self._seq[key] += 1
        self._w.add_message(self._ch[key], log_time=log_ns, data=data, publish_time=log_ns,
                            sequence=self._seq[key] & 0xFFFFFFFF)

    def raw(self, data: bytes, log_ns: int) -> None:
        self._add("raw", data, log_ns)

    def frames(self, payloads: list[bytes], log_ns: int) -> None:
        # one message per port read: u16 length + payload, repeated (stid.frames.v1)
        self._add("frames", b"".join(len(pl).to_bytes(2, "little") + pl for pl in payloads), log_ns)

    def json(self, key: str, doc: dict, log_ns: int) -> None:
        self._add(key, json.dumps(doc, separators=(",", ":")).encode(), log_ns)

    def metadata(self, name: str, doc: dict) -> None:
        self._w.add_metadata(name, {k: (v if isinstance(v, str) else json.dumps(v)) for k, v in doc.items()})

    def flush(self) -> None:
        self._w.flush()
        if self._fsync:
            os.fsync(self._f.fileno())
        self._last_flush = time.monotonic()

    def maybe_flush(self, period_s: float = 1.0) -> None:
        if time.monotonic() - self._last_flush >= period_s:
            self.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._w.finish()
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())
        self._f.close()
