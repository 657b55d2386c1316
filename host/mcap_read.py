"""Read a run written by stid-log back into arrays, complete or cut short.

The samples come from the binary ``/stid/frames`` channel (the accepted frames as
received), decoded in bulk with numpy: one Python step per frame, none per
sample. A file whose writer was killed has no summary section; it is read with
the non-seeking reader up to its last complete chunk and marked ``truncated``.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader

from host import protocol as p
from host.errors import HostError
from host.mcap_log import FRAMES_TOPIC

MAGIC = b"\x89MCAP0\r\n"


class LogReadError(HostError):
    """The file cannot be read as a stid log; the message says why and what to do."""


@dataclass
class LogData:
    path: str
    samples: np.ndarray  # LOADED_DTYPE: every wire field + index, segment, t_mcu_us (unwrapped), t_host_ns
    hellos: list = field(default_factory=list)  # (log_ns, doc)
    status: list = field(default_factory=list)  # (log_ns, doc)
    events: list = field(default_factory=list)  # (log_ns, doc)
    stats: dict | None = None
    metadata: dict = field(default_factory=dict)
    truncated: bool = False
    frames: int = 0

    @property
    def hello(self) -> dict:
        return self.hellos[0][1] if self.hellos else {}


# Every field of every protocol version's records (p.SAMPLE_FIELDS), whichever the file
# holds: steer_t_us is 0xFFFFFFFF (p.STEER_T_UNKNOWN) for protocol 1 samples; wheel1..3
# fields are 0xFFFF / 0xFFFFFFFF unless the samples came in four-wheel frames.
LOADED_DTYPE = np.dtype([(n, p.DECODED_DTYPE[n]) for n in p.SAMPLE_FIELDS] + [
    ("index", "<i8"), ("segment", "<i4"), ("t_mcu_us", "<i8"), ("t_host_ns", "<i8")])


# what a file cut short raises when the reader reaches the cut
TRUNCATION_ERRORS = (McapError, struct.error, ValueError, EOFError, IndexError, KeyError, OSError)


def iter_records(path: Path):
    """Yield every record of the file in order, complete or cut short.

    One streaming pass serves both cases: a file killed before ``finish()`` has
    no summary for a seeking reader to use. Returns (via ``StopIteration.value``)
    True if the file ended before its footer.
    """
    with open(path, "rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise LogReadError(f"{path} is not an MCAP file (no MCAP magic at the start): "
                               "corrupted, or not written by stid-log")
        f.seek(0)
        it = StreamReader(f, skip_magic=False).records
        footer_seen = False
        try:
            for rec in it:
                yield rec
            footer_seen = True
        except TRUNCATION_ERRORS:
            pass
        except Exception as e:  # zstandard raises its own error type on a torn chunk
            if type(e).__name__ != "ZstdError":
                raise
        return not footer_seen


def read_log(path) -> LogData:
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path} does not exist")
    if path.stat().st_size == 0:
        raise LogReadError(f"{path} is empty: the logger wrote nothing (did it receive any data?)")
    payloads, frame_ns = [], []
    data = LogData(str(path), np.zeros(0, LOADED_DTYPE))
    topics: dict[int, str] = {}
    gen = iter_records(path)
    try:
        while True:
            rec = next(gen)
            if isinstance(rec, Message):
                topic = topics.get(rec.channel_id)
                if topic == FRAMES_TOPIC:
                    for pl in split_frames(rec.data):
                        payloads.append(pl)
                        frame_ns.append(rec.log_time)
                elif topic in _JSON_TOPICS:
                    getattr(data, _JSON_TOPICS[topic]).append((rec.log_time, json.loads(rec.data)))
                elif topic == "/stid/stats":
                    data.stats = json.loads(rec.data)
            elif isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Metadata):
                data.metadata[rec.name] = {k: _maybe_json(v) for k, v in rec.metadata.items()}
    except StopIteration as stop:
        data.truncated = bool(stop.value)
    data.frames = len(payloads)
    data.samples = _decode_samples(payloads, np.asarray(frame_ns, dtype=np.int64))
    return data


def split_frames(blob: bytes) -> list[bytes]:
    """The frames of one /stid/frames message (stid.frames.v1: u16 length + payload, repeated)."""
    out, pos, n = [], 0, len(blob)
    while pos + 2 <= n:
        k = blob[pos] | blob[pos + 1] << 8
        out.append(blob[pos + 2:pos + 2 + k])
        pos += 2 + k
    return out


_JSON_TOPICS = {"/stid/hello": "hellos", "/stid/status": "status", "/stid/events": "events"}


def _maybe_json(v: str):
    try:
        return json.loads(v)
    except (ValueError, TypeError):
        return v


def _decode_samples(payloads: list[bytes], frame_ns: np.ndarray) -> np.ndarray:
    """All SAMPLES frames -> one array, MCU time unwrapped per firmware boot."""
    head = p.HEADER_SIZE + p.SAMPLES_HEAD_SIZE
    keep = [i for i, pl in enumerate(payloads)
            if len(pl) >= head and (pl[0], pl[1]) in p.RECORD_DTYPES]
    if not keep:
        return np.zeros(0, LOADED_DTYPE)
    counts = np.fromiter((payloads[i][p.HEADER_SIZE + 4] for i in keep), dtype=np.int64, count=len(keep))
    first = np.fromiter((int.from_bytes(payloads[i][p.HEADER_SIZE:p.HEADER_SIZE + 4], "little") for i in keep),
                        dtype=np.int64, count=len(keep))
    raw = p.samples_from_records((payloads[i][0], payloads[i][1], payloads[i][head:]) for i in keep)
    n = len(raw)
    out = np.zeros(n, LOADED_DTYPE)
    for name in p.SAMPLE_FIELDS:
        out[name] = raw[name]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out["index"] = np.repeat(first, counts) + (np.arange(n) - np.repeat(starts, counts))
    out["index"] %= p.MOD
    out["t_host_ns"] = np.repeat(frame_ns[keep], counts)
    # a new segment wherever the sample index runs backwards: the firmware restarted
    di = np.diff(out["index"]) % p.MOD
    restart = np.concatenate([[False], di > p.MOD // 2])
    out["segment"] = np.cumsum(restart)
    t = out["t_us"].astype(np.int64)
    dt = np.diff(t) % p.MOD
    dt[dt > p.MOD // 2] -= p.MOD
    # silent for more than half a wrap (a long unplug): take the wraps from the host clock
    dh = np.diff(out["t_host_ns"]) / 1000.0
    long_gap = dh > p.MOD / 2
    dt[long_gap] += np.round((dh[long_gap] - dt[long_gap]) / p.MOD).astype(np.int64) * p.MOD
    dt[restart[1:]] = 0
    tu = t[0] + np.concatenate([[0], np.cumsum(dt)])
    # each segment starts at its own first tick
    seg_start = np.flatnonzero(restart)
    for s in seg_start:
        tu[s:] += t[s] - tu[s]
    out["t_mcu_us"] = tu
    return out
