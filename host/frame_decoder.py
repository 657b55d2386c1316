"""Streaming decoder for the stid wire protocol.

Feed it byte chunks of any size and alignment; it returns the frames that pass
every check of PROTOCOL.md and counts everything else. It never raises on bad
input: a logger must survive any line noise, and the counts are the evidence of
what the link did.
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
_status = struct.Struct(p.STATUS_FMT)


@dataclass(slots=True)
class Frame:
    """One accepted frame. ``payload`` is the frame without COBS and without CRC."""

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

    def status(self) -> dict:
        return dict(zip(p.STATUS_FIELDS, _status.unpack_from(self.payload, p.HEADER_SIZE)))

    def hello(self) -> dict:
        return json.loads(self.body)


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
            errors["version"] += 1
            return None
        body_len = n - p.HEADER_SIZE - p.CRC_SIZE
        if ftype in p.SAMPLE_TYPES:
            rec = p.RECORD_DTYPES.get((version, ftype))
            if rec is None:  # a type this version does not have
                errors["type"] += 1
                return None
            if body_len < p.SAMPLES_HEAD_SIZE or body_len != p.SAMPLES_HEAD_SIZE + rec.itemsize * payload[p.HEADER_SIZE + 4]:
                errors["length"] += 1
                return None
        elif ftype == p.STATUS:
            if body_len != p.STATUS_SIZE:
                errors["length"] += 1
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
        return Frame(ftype, seq, t_us, payload[:-4])

    def _count_gap(self, seq: int) -> None:
        if self._last_seq is not None:
            gap = (seq - self._last_seq - 1) % p.MOD
            if gap > p.MOD // 2:  # seq went backwards: a restart, not 10^9 lost frames
                self.stats.restarts += 1
            else:
                self.stats.lost_frames += gap
        self._last_seq = seq
