"""The MCAP file of a logged run: what goes in it and how it stays safe.

Channels (all messages carry a host-clock log_time, ns since epoch):

| topic | encoding | content |
|---|---|---|
| `/stid/raw` | `stid.raw.v2` (no schema) | every byte read from the port, grouped per ~100 ms: u32 n, n u32 lengths, n u32 receive offsets [us] from the log time, then the n reads; a decoder bug can be fixed later |
| `/stid/frames` | `stid.frames.v2` (no schema) | the accepted frames (without COBS and CRC), grouped per ~100 ms: u32 n, n u16 lengths, n u32 receive offsets [us], then the n frames; the exact, fast path for loading (`stid.frames.v1`, u16 length + frame repeated, one message per read, in older logs) |
| `/stid/samples` | `json` + jsonschema | one message per sample in SI units (datasheet conversions, for viewing), log time = the sample's instant on the host clock from the clock model: Foxglove plots `/stid/samples.ay` directly |
| `/stid/status` | `json` + jsonschema | the firmware's STATUS frames |
| `/stid/hello` | `json` + jsonschema | the firmware's HELLO frames |
| `/stid/events` | `json` + jsonschema | connect, disconnect, reconnect, firmware restart |
| `/stid/stats` | `json` + jsonschema | link statistics, every second and at the end |

Metadata records: `stid.hello` (first HELLO of each boot), `stid.clock` (offset and
drift of MCU time against host time) and `stid.stats` (final link statistics).

No JSON integer exceeds 2^53 (JavaScript's exact range): host times in JSON are
seconds (floats); nanoseconds live only in log_time.

Crash safety: ``flush()`` closes the open chunk and writes it out at least once
per second (``Writer.flush``, mcap >= 1.6) and fsyncs, so a SIGKILL or a power cut
loses at most about a second. A file cut short is still readable up to its last
complete chunk, and ``host.repair`` rewrites it into a complete one.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from mcap.writer import CompressionType, Writer

_INT = {"type": "integer"}
_NUM = {"type": "number"}
_STR = {"type": "string"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_INT_OR_NULL = {"type": ["integer", "null"]}
_STR_OR_NULL = {"type": ["string", "null"]}
_COUNTS = {"type": "object", "additionalProperties": _INT}


def _obj(description: str, props: dict, required=None, extra=False) -> dict:
    out = {"type": "object", "description": description, "properties": props,
           "additionalProperties": extra}
    if required:
        out["required"] = list(required)
    return out


# One message per sample, in SI units, so that Foxglove's Plot panel plots e.g.
# /stid/samples.ay against log time (the host clock, from the clock model).
SI_FIELDS = {
    "t": ("s", "MCU time of the sample since the first sample of this boot (the crystal's clock)"),
    "ax": ("m/s^2", "longitudinal specific force, ADXL335 datasheet zero and sensitivity (uncalibrated)"),
    "ay": ("m/s^2", "lateral specific force, ISO 8855 (left positive), datasheet scale (uncalibrated)"),
    "az": ("m/s^2", "vertical specific force; null when the board does not sample it"),
    "r": ("rad/s", "yaw rate, ISO 8855 (left turn positive), LISY300AL datasheet zero and scale; "
                   "the gyro's bias is removed only by stid (from the stand-still)"),
    "steer_pulse": ("s", "width of the servo pulse the receiver sent (null: no pulse)"),
    "steer": ("rad", "front road-wheel angle by a typical servo map (1500 us centre, 500 us per 25 deg); "
                     "'stid calibrate' measures the car's own map, 'stid export' uses it"),
    "wheel_rate": ("rad/s", "angular speed of the (first) hall-sensed wheel from its last two edges, held"),
}
SI_SCHEMA = _obj(
    "One sample in SI units (ISO 8855 axes: x forward, y left, z up). Values are the sensors' "
    "datasheet conversions for viewing; 'stid export' gives calibrated ones. Exact counts are in "
    "/stid/frames.",
    {"boot": {"type": "string", "description": "firmware boot this sample belongs to"},
     "index": {"type": "integer", "description": "sample index since boot, modulo 2^30 (gaps: lost samples)"},
     **{k: {"type": ["number", "null"], "description": f"[{unit}] {text}"} for k, (unit, text) in SI_FIELDS.items()}},
    required=["boot", "index", "t", "ay", "r"])

_CHANNEL = {"anyOf": [{"type": "null"}, _obj(
    "an analog channel (null: the board does not sample it)",
    {"pin": _INT, "part": {**_STR, "description": "ADXL335, LISY300AL or divider"},
     "out": {**_STR, "description": "which output of the part"},
     "bandwidth_hz": {**_NUM_OR_NULL, "description": "[Hz] the analog output filter (first order)"}})]}
_WHEEL = _obj("a hall wheel-speed sensor", {"pin": _INT, "pulses_per_rev": _INT,
                                            "wheel": {**_STR, "description": "fl, fr, rl or rr"}})
HELLO_SCHEMA = _obj(
    "The firmware's HELLO: what the board samples and how (full or compact form)",
    {"proto": _INT, "fw": _STR_OR_NULL, "board": _STR_OR_NULL, "boot_id": _STR, "rate_hz": _NUM,
     "batch": _INT, "mod": {**_INT, "description": "the tick modulus (2^30 for MicroPython's ticks_us)"},
     "adc": _obj("the ADC", {"bits": _INT, "vref": {**_NUM, "description": "[V]"},
                             "unit": {**_STR, "description": "count (RP2040) or mV (ESP32)"}}),
     "adc_clip_v": {**_NUM_OR_NULL, "description": "[V] where the ADC clips (null: at its reference)"},
     "channels": _obj("the analog channels", {ch: _CHANNEL for ch in ("ax", "ay", "az", "yaw", "vbat")}),
     "steer": _obj("the steering pulse input", {"pin": _INT, "period_us": _INT, "timeout_us": _INT}),
     "wheel": _WHEEL, "wheels": {"type": "array", "items": _WHEEL},
     "uid": {**_STR_OR_NULL, "description": "the MCU's unique id (hex): the same board across reboots"},
     "micropython": _STR_OR_NULL, "timer": {**_STR_OR_NULL, "description": "hard or soft"},
     "reset_cause": _STR_OR_NULL,
     "link": {"anyOf": [{"type": "null"}, _obj("the serial link", {
         "kind": {**_STR, "description": "usb, uart or pipe"}, "baud": _INT_OR_NULL,
         "bytes_per_sample": {**_NUM, "description": "on the wire, framing shared by a batch"}})]},
     "capture": _obj("how the board captures its inputs (absent: both by the CPU)", {
         "adc": {**_STR, "description": "cpu (read in the timer interrupt) or dma (a hardware scan)"},
         "servo": {**_STR, "description": "irq (pin interrupts) or pio (a PIO state machine)"}}),
     "sim": {"type": "boolean"}, "hello": {**_STR_OR_NULL, "description": "full or compact"},
     "supplied_from": {**_STR, "description": "set when this HELLO was not received but taken "
                                              "from a vehicle file or an earlier log"},
     "unknown": {"type": "object", "description": "keys this stid does not know (a newer firmware, a vehicle "
                                                  "file's [board] table), kept as they came; dotted paths for "
                                                  "keys inside the tables above"}},
    required=["boot_id"])


def conform(doc, schema: dict, unknown: dict, path: str = ""):
    """``doc`` with every key its (strict) schema does not declare moved into ``unknown``,
    under its dotted path: the message validates, and nothing sent is dropped."""
    if isinstance(schema, dict) and "anyOf" in schema:
        objs = [s for s in schema["anyOf"] if s.get("type") == "object"]
        return conform(doc, objs[0], unknown, path) if objs and isinstance(doc, dict) else doc
    if not isinstance(doc, dict) or not isinstance(schema, dict) or schema.get("type") != "object":
        if isinstance(doc, list) and isinstance(schema, dict) and "items" in schema:
            return [conform(d, schema["items"], unknown, f"{path}{i}.") for i, d in enumerate(doc)]
        return doc
    props = schema.get("properties", {})
    if schema.get("additionalProperties", True) is not False:
        return doc
    out = {}
    for k, v in doc.items():
        if k in props:
            out[k] = conform(v, props[k], unknown, f"{path}{k}.")
        else:
            unknown[f"{path}{k}"] = v
    return out


def hello_message(doc: dict) -> dict:
    """A HELLO as /stid/hello carries it (see ``conform``; the reader merges ``unknown`` back)."""
    unknown = {}
    out = conform({k: v for k, v in doc.items() if k != "unknown"}, HELLO_SCHEMA, unknown)
    unknown.update(doc.get("unknown") or {})
    if unknown:
        out["unknown"] = unknown
    return out


SCHEMAS = {
    "stid.Sample": SI_SCHEMA,
    "stid.Status": _obj(
        "The firmware's STATUS frame (about once a second)",
        {"boot": _STR, "seq": {**_INT, "description": "frame sequence number, modulo 2^30"},
         "uptime_ms": _INT, "samples": {**_INT, "description": "samples taken since boot"},
         "overruns": {**_INT, "description": "samples lost in the MCU's ring (host too slow)"},
         "frames": _INT, "tx_short": {**_INT, "description": "writes the USB port cut short"},
         "isr_max_us": _INT, "isr_last_us": _INT, "ring_peak": _INT, "ring_size": _INT,
         "missed": {**_INT_OR_NULL, "description": "timer periods with no sample (protocol 3; null before)"},
         "late_max_us": {**_INT_OR_NULL, "description": "largest lateness of a sample [us] (protocol 3)"}},
        required=["boot", "seq", "uptime_ms", "samples", "overruns"]),
    "stid.Hello": HELLO_SCHEMA,
    "stid.Event": _obj(
        "Something that happened to the link or the run",
        {"event": {**_STR, "description": "connect, disconnect, reconnect, boot, other_board, rejects, "
                                          "silence, no_hello, hello, stop"},
         "detail": _STR, "boot": _STR},
        required=["event", "detail"]),
    "stid.Stats": _obj(
        "Link statistics so far (every second and at the end)",
        {"bytes": _INT, "frames": {**_COUNTS, "description": "accepted frames by type"},
         "errors": {**_COUNTS, "description": "rejected frames by reason"},
         "lost_frames": _INT, "restarts": {**_INT, "description": "firmware boots after the first seen"},
         "samples": _INT, "missing_samples": _INT,
         "mcu_overruns": _INT,
         "mcu_missed": {**_INT, "description": "timer periods the car could not sample (its STATUS `missed`)"},
         "hello_seen": {"type": "boolean"},
         "gaps": {"type": "array", "items": _obj("an unplug", {
             "from_s": {**_NUM, "description": "host time [s since 1970]"}, "to_s": _NUM, "seconds": _NUM})},
         "car_restarts": {"type": "array", "items": _obj(
             "a restart of the car (watchdog, brown-out, reset button): each boot after the first",
             {"boot": {**_STR, "description": "the new boot's id"},
              "reset_cause": {**_STR_OR_NULL, "description": "from its HELLO (null: none came)"},
              "gap_s": {**_NUM_OR_NULL, "description": "seconds without samples across the restart"}})}}),
}
TOPICS = {
    "samples": ("/stid/samples", "stid.Sample"),
    "status": ("/stid/status", "stid.Status"),
    "hello": ("/stid/hello", "stid.Hello"),
    "events": ("/stid/events", "stid.Event"),
    "stats": ("/stid/stats", "stid.Stats"),
}
SI_TOPIC = "/stid/samples"
STATS_TOPIC = "/stid/stats"
RAW_TOPIC = "/stid/raw"
FRAMES_TOPIC = "/stid/frames"
# Frames and raw bytes are grouped per GROUP_NS of receive time (one message per ~100 ms,
# not per port read): loading a 10-minute run then steps over ~12k records, not ~60k.
# Each entry keeps its own receive time as an offset [us] from the message's log time.
# stid.frames.v2: u32 n, n x u16 length, n x u32 dt_us, then the n frames (without COBS
# and CRC) back to back: the table up front lets the loader take a message's frames with
# numpy instead of stepping through them.
FRAME_ENCODING = "stid.frames.v2"
FRAME_ENCODING_V1 = "stid.frames.v1"  # older logs: (u16 length, frame) repeated, one message per read
RAW_ENCODING = "stid.raw.v2"  # u32 n, n x u32 length, n x u32 dt_us, then the n reads back to back
RAW_ENCODING_V1 = "stid.raw"  # older logs: one message per read
GROUP_NS = 100_000_000
PROFILE = "stid"
JSON_SAFE = 1 << 53
# Channel metadata of /stid/samples: its messages are written in chunks of their own, never
# mixed with other channels, so a loader that does not need them skips a whole chunk at once
# (after its CRC) instead of stepping over 600k records of a 10-minute run.
OWN_CHUNKS = {"stid.chunks": "own"}
SI_BATCH = 5000  # per-sample messages held before they are written as their own chunk(s)  # JavaScript (Foxglove) reads integers exactly only up to here


class McapLog:
    """Write a run. Every write goes to the open chunk; ``flush`` makes it durable."""

    def __init__(self, path, fsync: bool = True, chunk_size: int = 256 * 1024, exclusive: bool = False):
        self.path = str(path)
        # exclusive: never over an existing file (a recording replaces no run, not even one
        # another logger started in the same second); FileExistsError otherwise
        self._f = open(self.path, "xb" if exclusive else "wb")
        self._fsync = fsync
        # the data section CRC covers the records outside chunks (metadata), which have none
        self._w = Writer(self._f, chunk_size=chunk_size, compression=CompressionType.ZSTD,
                         enable_data_crcs=True)
        self._w.start(profile=PROFILE, library="stid-log")
        self._ch = {}
        self._seq = {}
        for key, (topic, schema) in TOPICS.items():
            sid = self._w.register_schema(schema, "jsonschema", json.dumps(SCHEMAS[schema]).encode())
            self._ch[key] = self._w.register_channel(topic, "json", sid, OWN_CHUNKS if key == "samples" else {})
        self._ch["raw"] = self._w.register_channel(RAW_TOPIC, RAW_ENCODING, 0)
        self._ch["frames"] = self._w.register_channel(FRAMES_TOPIC, FRAME_ENCODING, 0)
        for key in self._ch:
            self._seq[key] = 0
        self._last_flush = time.monotonic()
        self._si: list = []  # (json line, log time) waiting to be written as their own chunk
        self._groups: dict = {}  # key -> [first log time, entry parts] of the open frames/raw group
        self.closed = False

    def _add(self, key: str, data: bytes, log_ns: int) -> None:
        self._seq[key] += 1
        self._w.add_message(self._ch[key], log_time=log_ns, data=data, publish_time=log_ns,
                            sequence=self._seq[key] & 0xFFFFFFFF)

    def raw(self, data: bytes, log_ns: int) -> None:
        self._group("raw", log_ns, [data])

    def frames(self, payloads: list[bytes], log_ns: int) -> None:
        self._group("frames", log_ns, payloads)

    def _group(self, key: str, log_ns: int, items: list) -> None:
        g = self._groups.get(key)
        if g is not None and log_ns - g[0] >= GROUP_NS:
            self._write_group(key)
            g = None
        if g is None:
            g = self._groups[key] = (log_ns, [], [])
        dt = max(0, (log_ns - g[0]) // 1000)
        g[1].extend(items)
        g[2].extend([dt] * len(items))

    def _write_group(self, key: str) -> None:
        g = self._groups.pop(key, None)
        if g is None:
            return
        t0, items, dts = g
        width = "<u2" if key == "frames" else "<u4"
        head = (len(items).to_bytes(4, "little") + np.array([len(x) for x in items], width).tobytes()
                + np.array(dts, "<u4").tobytes())
        self._add(key, head + b"".join(items), t0)

    def _write_groups(self) -> None:
        for key in list(self._groups):
            self._write_group(key)

    def json(self, key: str, doc: dict, log_ns: int) -> None:
        if key == "hello":
            doc = hello_message(doc)
        self._add(key, json.dumps(doc, separators=(",", ":")).encode(), log_ns)

    def sample_messages(self, lines: list[bytes], log_ns) -> None:
        """Per-sample JSON messages (already encoded), each at its own log time; written
        at the next flush (or every SI_BATCH) in chunks of their own (OWN_CHUNKS)."""
        self._si.extend(zip(lines, log_ns))
        if len(self._si) >= SI_BATCH:
            self._write_si()

    def _write_si(self) -> None:
        if not self._si:
            return
        self._w.flush()  # close the chunk of the other channels first
        ch = self._ch["samples"]
        seq = self._seq["samples"]
        add = self._w.add_message
        for line, t in self._si:
            seq += 1
            add(ch, log_time=t, data=line, publish_time=t, sequence=seq & 0xFFFFFFFF)
        self._seq["samples"] = seq
        self._si.clear()
        self._w.flush()

    def metadata(self, name: str, doc: dict) -> None:
        self._w.add_metadata(name, {k: (v if isinstance(v, str) else json.dumps(v)) for k, v in doc.items()})

    def flush(self) -> None:
        self._write_groups()
        self._write_si()
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
        self._write_groups()
        self._write_si()
        self._w.finish()
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())
        self._f.close()
