"""Streaming decoder for the stid wire protocol.

Feed it byte chunks of any size and alignment; it returns the frames that pass
every check of PROTOCOL.md and counts everything else. It never raises on bad
input: a logger must survive any line noise, and the counts are the evidence of
what the link did.

Contract with the logger (issue 11/12; protocol version 3)
-----------------------------------------------------------
* ``Frame.type == p.HELLO`` for EVERY configuration frame: the full JSON HELLO
  (type byte 1) and the compact binary HELLO (type byte 5, ``p.HELLO_COMPACT``,
  ~80 bytes, sent every second; the JSON one every 10 s). ``Frame.compact`` tells
  them apart; ``Frame.payload[1]`` keeps the real type byte.
  ``stats.frames`` counts them apart: ``"hello"`` and ``"hello_compact"``.
* ``Frame.hello()`` returns the same normalised dict for both, with keys:
  ``proto`` int, ``fw`` str, ``board`` str, ``boot_id`` str (8 hex digits),
  ``rate_hz`` int, ``batch`` int, ``mod`` int (2^30),
  ``adc`` {bits, vref, unit}, ``adc_clip_v`` float|None,
  ``channels`` {ax, ay, az, yaw, vbat: {part, out, bandwidth_hz[, pin]} | None},
  ``steer`` {period_us, timeout_us[, pin]},
  ``wheels`` [{pulses_per_rev, wheel[, pin]}, ...] (1 or 4), ``wheel`` (= wheels[0]),
  ``uid`` str|None (hex of machine.unique_id()), ``micropython`` str|None ("1.26.0"),
  ``timer`` "hard"|"soft"|None, ``reset_cause`` str|None ("power_on", "hard",
  "watchdog", "deepsleep", "soft", "unknown"),
  ``link`` {kind: "usb"|"uart"|"pipe", baud: int|None, bytes_per_sample: float}|None,
  ``sim`` bool (the simulated board), ``hello`` "full"|"compact" (which frame it came from).
  Pins are absent from the compact form. Keys a version-1/2 HELLO lacks read None
  (``sim`` False); a version-3 full HELLO no longer sends ``wheel``: it is restored.
  A full HELLO may carry further keys; they are passed through.
* The port's default baud: ``p.LINK_BAUD`` (921600, what the ESP32 firmware sets;
  USB-CDC ignores it). ``stid-log --baud`` should default to it.
* ``Frame.status()`` returns the STATUS fields; version 3 adds ``missed`` (timer
  periods in which no sample was taken: the sample index still advanced, so the
  host sees a gap) and ``late_max_us`` (largest lateness of a sample behind its
  nominal instant since the last STATUS: the soft-timer jitter). Version 1/2
  STATUS read ``missed`` = ``late_max_us`` = None.
* Reject reasons (``stats.errors`` keys, ``p.ERROR_KINDS``): ``cobs``, ``short``,
  ``crc``, ``version`` (0 or otherwise not a version), ``version_newer`` (a CRC-valid
  frame of a protocol version newer than this host knows: "needs a newer stid"),
  ``type``, ``length``, ``hello`` (bad JSON or bad compact body), ``too_long``.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field

from cobs import cobs

from host import protocol as p

_header = struct.Struct(p.HEADER_FMT)
_crc = struct.Struct("<I")
_samples_head = struct.Struct(p.SAMPLES_HEAD_FMT)
_status = {v: (struct.Struct(fmt), names) for v, (fmt, names) in p.STATUS_LAYOUTS.items()}
_hello_c = struct.Struct(p.HELLO_C_FMT)
assert _hello_c.size == p.HELLO_C_FIXED


@dataclass(slots=True)
class Frame:
    """One accepted frame. ``payload`` is the frame without COBS and without CRC.

    ``type`` is the frame's kind: ``p.HELLO`` for both HELLO forms (``compact``
    says which), so a consumer handles configuration in one place."""

    type: int
    seq: int
    t_us: int
    payload: bytes

    @property
    def version(self) -> int:
        return self.payload[0]

    @property
    def body(self) -> bytes:
        return self.payload[p.HEADER_SIZE:]

    def samples_index(self) -> int:
        return _samples_head.unpack_from(self.payload, p.HEADER_SIZE)[0]

    def samples_count(self) -> int:
        return self.payload[p.HEADER_SIZE + 4]

    def samples_bytes(self) -> bytes:
        """The raw sample records (layout: ``p.RECORD_DTYPES[(version, type)]``)."""
        return self.payload[p.HEADER_SIZE + p.SAMPLES_HEAD_SIZE:]

    def samples(self):
        """The samples as a ``p.DECODED_DTYPE`` array (fields this layout lacks filled)."""
        return p.records_to_samples(self.version, self.type, self.samples_bytes())

    @property
    def compact(self) -> bool:
        """A compact binary HELLO (type byte 5)."""
        return self.payload[1] == p.HELLO_COMPACT

    def status(self) -> dict:
        """STATUS fields; ``missed`` and ``late_max_us`` are None before version 3."""
        st, names = _status[self.version]
        out = dict.fromkeys(p.STATUS_FIELDS)
        out.update(zip(names, st.unpack_from(self.payload, p.HEADER_SIZE)))
        return out

    def hello(self) -> dict:
        """The configuration as one normalised dict, from either HELLO form."""
        if self.compact:
            return decode_compact_hello(self.body, self.version)
        return normalise_hello(json.loads(self.body))


def normalise_hello(doc: dict) -> dict:
    """A full (JSON) HELLO with the keys of every version present (absent ones None)."""
    for key in p.HELLO_V3_KEYS:
        doc.setdefault(key, None)
    if "wheel" not in doc and doc.get("wheels"):  # version 3 sends `wheels` only
        doc["wheel"] = doc["wheels"][0]
    doc.setdefault("sim", False)
    doc["hello"] = "full"
    return doc


def decode_compact_hello(body: bytes, version: int = p.VERSION) -> dict:
    """The compact binary HELLO (PROTOCOL.md, HELLO_COMPACT) as the full HELLO's dict
    (pins absent). Raises ValueError on a body that does not follow the layout."""
    if len(body) < p.HELLO_C_FIXED:
        raise ValueError("compact HELLO too short")
    f = dict(zip(p.HELLO_C_FIELDS, _hello_c.unpack_from(body)))
    if len(body) != p.HELLO_C_FIXED + f["uid_len"]:
        raise ValueError("compact HELLO length does not match its uid_len")

    def code(table, k):
        if k >= len(table):
            raise ValueError(f"compact HELLO code {k} out of range")
        return table[k]

    channels = {}
    for ch in p.CHANNEL_NAMES:
        part = code(p.HELLO_C_PARTS, f[f"{ch}_part"])
        bw = f[f"{ch}_bw"]
        channels[ch] = None if part is None else {"part": part[0], "out": part[1],
                                                  "bandwidth_hz": bw or None}
    n = f["n_wheels"]
    if n not in (1, 4):
        raise ValueError("compact HELLO: one or four wheels")
    wheels = [{"pulses_per_rev": f["wheel_ppr"], "wheel": code(p.HELLO_C_WHEELS, k)} for k in f["wheel_pos"][:n]]
    kind = code(p.HELLO_C_LINKS, f["link_kind"])
    mp = (f["mp0"], f["mp1"], f["mp2"])
    uid = body[p.HELLO_C_FIXED:]
    doc = {
        "proto": version, "fw": "%d.%d.%d" % (f["fw0"], f["fw1"], f["fw2"]),
        "board": code(p.HELLO_C_BOARDS, f["board"]), "boot_id": "%08x" % f["boot_id"],
        "rate_hz": f["rate_hz"], "batch": f["batch"], "mod": p.MOD,
        "adc": {"bits": f["adc_bits"], "vref": f["adc_vref_mv"] / 1000,
                "unit": code(p.HELLO_C_ADC_UNITS, f["adc_unit"])},
        "adc_clip_v": f["adc_clip_mv"] / 1000 if f["adc_clip_mv"] else None,
        "channels": channels,
        "steer": {"period_us": f["steer_period_us"], "timeout_us": f["steer_timeout_us"]},
        "wheel": wheels[0], "wheels": wheels,
        "uid": uid.hex() if uid else None,
        "micropython": "%d.%d.%d" % mp if any(mp) else None,
        "timer": "hard" if f["flags"] & p.HELLO_C_FLAG_HARD_TIMER else "soft",
        "reset_cause": code(p.HELLO_C_RESET_CAUSES, f["reset_cause"]),
        "link": None if kind is None else {"kind": kind, "baud": f["link_baud"] or None,
                                           "bytes_per_sample": f["link_bps_x100"] / 100},
        "sim": bool(f["flags"] & p.HELLO_C_FLAG_SIM),
        "hello": "compact",
    }
    if f["flags"] & (p.HELLO_C_FLAG_ADC_DMA | p.HELLO_C_FLAG_SERVO_PIO | p.HELLO_C_FLAG_SERVO_PCNT | p.HELLO_C_FLAG_HALL_PCNT):
        servo = ("pio" if f["flags"] & p.HELLO_C_FLAG_SERVO_PIO else
                 "pcnt" if f["flags"] & p.HELLO_C_FLAG_SERVO_PCNT else "irq")
        doc["capture"] = {"adc": "dma" if f["flags"] & p.HELLO_C_FLAG_ADC_DMA else "cpu", "servo": servo}
        if f["flags"] & p.HELLO_C_FLAG_HALL_PCNT:
            doc["capture"]["hall"] = "pcnt"
    # absent: cpu and irq (and hall irq)
    return doc


@dataclass
class DecoderStats:
    """What the link delivered. ``errors`` counts rejected chunks by reason."""

    bytes: int = 0
    frames: dict = field(default_factory=lambda: {name: 0 for name in p.TYPE_NAMES.values()})
    errors: dict = field(default_factory=lambda: {kind: 0 for kind in p.ERROR_KINDS})
    lost_frames: int = 0  # by seq gaps
    restarts: int = 0  # seq jumped backwards or far ahead: firmware rebooted

    @property
    def accepted(self) -> int:
        return sum(self.frames.values())

    @property
    def rejected(self) -> int:
        return sum(self.errors.values())

    def as_dict(self) -> dict:
        return {"bytes": self.bytes, "frames": dict(self.frames), "errors": dict(self.errors),
                "lost_frames": self.lost_frames, "restarts": self.restarts}


class FrameDecoder:
    """Split a byte stream into validated frames.

    Parameters
    ----------
    track_seq : bool
        Count lost frames from sequence gaps (default True).
    """

    def __init__(self, track_seq: bool = True):
        self.stats = DecoderStats()
        self._pending = bytearray()
        self._overflow = False  # discarding an over-long run until the next delimiter
        self._track_seq = track_seq
        self._last_seq: int | None = None

    def reset_link(self) -> None:
        """Forget a half-received frame (call after a disconnect)."""
        self._pending.clear()
        self._overflow = False

    def feed(self, data: bytes) -> list[Frame]:
        self.stats.bytes += len(data)
        out: list[Frame] = []
        parts = data.split(b"\x00")
        last = parts.pop()  # bytes after the final delimiter: an unfinished frame
        for i, part in enumerate(parts):
            if i == 0 and (self._pending or self._overflow):
                overflow = self._overflow or len(self._pending) + len(part) > p.MAX_WIRE
                chunk = b"" if overflow else bytes(self._pending) + part
                self._pending.clear()
                self._overflow = False
                if overflow:
                    self.stats.errors["too_long"] += 1
                    continue
            else:
                chunk = part
            if chunk:
                frame = self._check(chunk)
                if frame is not None:
                    out.append(frame)
        if last:
            if self._overflow:
                pass
            elif len(self._pending) + len(last) > p.MAX_WIRE:
                self._pending.clear()
                self._overflow = True
            else:
                self._pending += last
        return out

    def _check(self, chunk: bytes) -> Frame | None:
        errors = self.stats.errors
        if len(chunk) > p.MAX_WIRE:
            errors["too_long"] += 1
            return None
        try:
            payload = cobs.decode(chunk)
        except cobs.DecodeError:
            errors["cobs"] += 1
            return None
        n = len(payload)
        if n < p.HEADER_SIZE + p.CRC_SIZE:
            errors["short"] += 1
            return None
        if zlib.crc32(memoryview(payload)[:-4]) != _crc.unpack_from(payload, n - 4)[0]:
            errors["crc"] += 1
            return None
        version, ftype, seq, t_us = _header.unpack_from(payload)
        if version not in p.VERSIONS:
            # past the CRC: a real frame of a protocol this host does not know yet
            errors["version_newer" if version > max(p.VERSIONS) else "version"] += 1
            return None
        body_len = n - p.HEADER_SIZE - p.CRC_SIZE
        if ftype in p.SAMPLE_TYPES:
            rec = p.RECORD_DTYPES.get((version, ftype))
            if rec is None:  # a type this version does not have
                errors["type"] += 1
                return None
            # (n is 1 to the most a frame holds: PROTOCOL.md; a frame of none is no frame the firmware sends)
            if body_len <= p.SAMPLES_HEAD_SIZE or body_len != p.SAMPLES_HEAD_SIZE + rec.itemsize * payload[p.HEADER_SIZE + 4]:
                errors["length"] += 1
                return None
        elif ftype == p.STATUS:
            if body_len != p.STATUS_SIZES[version]:
                errors["length"] += 1
                return None
        elif ftype == p.HELLO_COMPACT and version >= 3:
            try:
                decode_compact_hello(payload[p.HEADER_SIZE:n - 4], version)
            except (ValueError, struct.error):
                errors["hello"] += 1
                return None
        elif ftype == p.HELLO:
            try:
                doc = json.loads(payload[p.HEADER_SIZE:n - 4])
                if not isinstance(doc, dict):
                    raise ValueError
            except (ValueError, UnicodeDecodeError):
                errors["hello"] += 1
                return None
        else:
            errors["type"] += 1
            return None
        self.stats.frames[p.TYPE_NAMES[ftype]] += 1
        if self._track_seq:
            self._count_gap(seq)
        return Frame(p.HELLO if ftype == p.HELLO_COMPACT else ftype, seq, t_us, payload[:-4])

    def _count_gap(self, seq: int) -> None:
        if self._last_seq is not None:
            gap = (seq - self._last_seq - 1) % p.MOD
            if gap > p.MOD // 2:  # seq went backwards: a restart, not 10^9 lost frames
                self.stats.restarts += 1
            else:
                self.stats.lost_frames += gap
        self._last_seq = seq
