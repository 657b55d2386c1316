"""Read a run written by stid-log back into arrays, complete or cut short.

The samples come from the binary ``/stid/frames`` channel (the accepted frames as
received), decoded in bulk with numpy: one Python step per frame, none per
sample. Every chunk must pass its CRC before anything in it is used
(``host.mcap_scan``): a damaged file gives back what is intact and says what was
skipped and where (``LogData.damage``); a file whose writer was killed is read up
to its last complete chunk and marked ``truncated``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from host import protocol as p
from host.errors import HostError
from host.mcap_log import FRAME_ENCODING, FRAME_ENCODING_V1, FRAMES_TOPIC, PROFILE, RAW_TOPIC, SI_TOPIC, STATS_TOPIC
from host.mcap_scan import MAGIC, Damage, Scan, scan

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
    damage: list = field(default_factory=list)  # Damage: stretches skipped because they failed a check
    data_crc_ok: bool | None = None
    bad_frames: int = 0  # frames in intact chunks that still do not decode (a writer bug, never data)
    missing_frames: int = 0  # frames stid-log counted when it closed the file that the file does not hold

    @property
    def hello(self) -> dict:
        return self.hellos[0][1] if self.hellos else {}

    def damage_note(self) -> str | None:
        """One sentence on what was skipped and where, or None for an intact file."""
        if not self.damage and self.data_crc_ok is not False and not self.bad_frames and not self.missing_frames:
            return None
        parts = []
        took = [d for d in self.damage if d.took_samples is not False]
        spared = [d for d in self.damage if d.took_samples is False]
        if took:
            lost = sum(d.length for d in took)
            t0 = self.samples["t_host_ns"][0] if len(self.samples) else None
            where = []
            for d in took[:3]:
                if t0 is not None and d.after_ns is not None and d.before_ns is not None:
                    where.append(f"{(d.after_ns - t0) / 1e9:.1f}-{(d.before_ns - t0) / 1e9:.1f} s")
                elif d.before_ns is None:
                    where.append(f"the end (from byte {d.offset})")
                else:
                    where.append(f"byte {d.offset}")
            more = f" and {len(took) - 3} more" if len(took) > 3 else ""
            parts.append(f"{len(took)} damaged stretch(es), {lost} bytes, failed their checks and "
                         f"were skipped (at {', '.join(where)}{more}; {took[0].reason}); the samples "
                         "there are missing, never guessed")
        if spared:
            parts.append(f"{len(spared)} damaged stretch(es), {sum(d.length for d in spared)} bytes, failed their "
                         f"checks and were skipped ({spared[0].reason}); they held no samples (other channels, "
                         "such as the per-sample view for Foxglove): every sample is intact")
        if self.data_crc_ok is False and not self.damage:
            parts.append("a record outside the data chunks is damaged (the data section CRC does not match): "
                         "the samples are intact, metadata may not be")
        if self.bad_frames:
            parts.append(f"{self.bad_frames} logged frames do not decode and were left out")
        if self.missing_frames:
            parts.append(f"stid-log counted {self.frames + self.missing_frames} frames when it closed the file, "
                         f"{self.frames} are in it: the last {self.missing_frames} are missing (a copy cut short or "
                         "filtered by another tool?), never guessed; the original log has them")
        return "; ".join(parts)


# Every field of every protocol version's records (p.SAMPLE_FIELDS), whichever the file
# holds: steer_t_us is 0xFFFFFFFF (p.STEER_T_UNKNOWN) for protocol 1 samples; wheel1..3
# fields are 0xFFFF / 0xFFFFFFFF unless the samples came in four-wheel frames.
LOADED_DTYPE = np.dtype([(n, p.DECODED_DTYPE[n]) for n in p.SAMPLE_FIELDS] + [
    ("index", "<i8"), ("segment", "<i4"), ("t_mcu_us", "<i8"), ("t_host_ns", "<i8")])

REPAIR_METADATA = "stid.repair"  # what a repaired file's original lacked (host.repair)

# topics the loader never needs: the raw bytes and the per-sample view (both derived or archival)
_SKIP_ON_LOAD = frozenset({RAW_TOPIC, SI_TOPIC})


def scan_log(path, skip_topics=frozenset(), chunks: dict | None = None) -> Scan:
    """Check and scan a stid log: a readable MCAP file from stid-log (or its repair), else
    LogReadError with what to do."""
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path} does not exist")
    if path.is_dir():
        raise LogReadError(f"{path} is a directory: give an MCAP file")
    buf = path.read_bytes()
    if not buf:
        raise LogReadError(f"{path} is empty: the logger wrote nothing (did it receive any data?)")
    if not buf.startswith(MAGIC):
        raise LogReadError(f"{path} is not an MCAP file (no MCAP magic at the start): "
                           "corrupted, or not written by stid-log")
    sc = scan(buf, skip_topics, chunks)
    topics = {c.topic for c in sc.channels.values()}
    profile = sc.header.profile if sc.header is not None else None
    if profile is None and not topics:
        raise LogReadError(f"{path} holds nothing readable ({len(buf)} bytes"
                           + (": cut short before its first chunk" if sc.truncated else ": damaged at its start")
                           + "); there is nothing to recover from it")
    if profile != PROFILE and not any(t.startswith("/stid/") for t in topics):
        what = f"profile {profile!r}" if profile is not None else "no readable header"
        shown = ", ".join(sorted(topics)[:4]) or "none readable"
        raise LogReadError(f"{path} is an MCAP file but not a stid log ({what}; topics: {shown}); "
                           "give a file written by stid-log or stid-sim")
    return sc


def read_log(path, chunks: dict | None = None) -> LogData:
    """``chunks``: kept between reads of a file that grows (host.mcap_scan.scan)."""
    path = Path(path)
    sc = scan_log(path, _SKIP_ON_LOAD, chunks)
    topics = {cid: c.topic for cid, c in sc.channels.items()}
    data = LogData(str(path), np.zeros(0, LOADED_DTYPE), truncated=sc.truncated, damage=sc.damage,
                   data_crc_ok=sc.data_crc_ok)
    blobs, blob_ns, seqs = [], [], []
    frames_ch = next((c for c in sc.channels.values() if c.topic == FRAMES_TOPIC), None)
    if frames_ch is not None and frames_ch.message_encoding not in (FRAME_ENCODING, FRAME_ENCODING_V1):
        raise LogReadError(f"{path} was written by a newer stid-log (frames as {frames_ch.message_encoding!r}): "
                           "this log needs a newer stid (pip install -U stid)")
    v2 = frames_ch is None or frames_ch.message_encoding == FRAME_ENCODING
    unnamed = 0
    for m in sc.messages:
        topic = topics.get(m.channel_id)
        if topic == FRAMES_TOPIC:
            blobs.append(m.data)
            blob_ns.append(m.log_time)
            seqs.append(m.sequence)
        elif topic in _JSON_TOPICS:
            doc = _json_doc(m.data)
            if doc is not None:
                if topic == "/stid/hello" and isinstance(doc.get("unknown"), dict):
                    # keys the writer did not know (mcap_log.hello_message): top-level ones as sent
                    extra = doc.pop("unknown")
                    doc.update({k: v for k, v in extra.items() if "." not in k and k not in doc})
                getattr(data, _JSON_TOPICS[topic]).append((m.log_time, doc))
        elif topic == STATS_TOPIC:
            data.stats = _json_doc(m.data) or data.stats
        elif topic is None:
            unnamed += 1
    if unnamed:
        # the definition of their channel was in a damaged chunk, and the summary cannot name it
        data.damage.append(Damage(0, 0, f"{unnamed} intact messages on a channel whose definition was lost"))
    for rec in sc.metadata:
        data.metadata[rec.name] = {k: _maybe_json(v) for k, v in rec.metadata.items()}
    data.damage.extend(_repaired_damage(data.metadata.get(REPAIR_METADATA)))
    _match_gaps(data, seqs, blob_ns)
    frames = FrameTable.from_messages(blobs, blob_ns, v2)
    if not data.hellos:
        # the /stid/hello messages were in damaged chunks: the HELLO frames are in /stid/frames too
        data.hellos = _hellos_from_frames(frames)
    data.frames = len(frames.offset)
    data.samples, data.bad_frames = _decode_samples(frames)
    data.missing_frames = _missing_at_the_end(data)
    return data


def _missing_at_the_end(data: LogData) -> int:
    """Frames stid-log counted (its closing ``stid.stats``) that the file does not hold,
    where no damaged record and no gap in the messages' numbering shows them missing: they
    were lost after the last frame the file holds, which no check inside the file can see."""
    st = data.metadata.get("stid.stats")
    if data.damage or not isinstance(st, dict) or not isinstance(st.get("frames"), dict):
        return 0  # damage already says what is missing; no closing count (a crash, another logger)
    try:
        counted = sum(int(v) for v in st["frames"].values())
    except (TypeError, ValueError):
        return 0
    return max(counted - data.frames, 0)


def _repaired_damage(meta) -> list:
    """What a repaired file's original lacked (metadata has no CRC: take only well-formed entries)."""
    out = []
    entries = meta.get("damage") if isinstance(meta, dict) else None
    for d in entries if isinstance(entries, list) else []:
        if not isinstance(d, dict):
            continue
        nums = [d.get(k) for k in ("offset", "length", "after_ns", "before_ns")]
        if not all(v is None or (isinstance(v, int) and not isinstance(v, bool)) for v in nums):
            continue
        out.append(Damage(nums[0] or 0, nums[1] or 0, f"left out by stid repair: {d.get('reason', 'damaged')}",
                          nums[2], nums[3]))
    return out


def _match_gaps(data: LogData, seqs: list, times: list) -> None:
    """The writer numbers /stid/frames messages 1, 2, 3, ...: a gap in the numbering is the
    frames a damaged stretch took. That places the stretch exactly, between the intact frame
    messages either side, and a damaged stretch with no gap took no frames (its records held
    other channels: each second's per-sample view, for instance). A gap where no damage was
    found means something was skipped unnoticed: say so rather than trust it."""
    if len(seqs) < 2:
        return
    s = np.asarray(seqs, dtype=np.int64)
    t = np.asarray(times, dtype=np.int64)
    # a damaged record (found here, or left out by a repair) between intact frame messages took
    # none of them unless a gap says so; one before the first or after the last may have taken
    # some without a gap to show it (then it is not said either way)
    first, last = int(t[0]), int(t[-1])
    for d in data.damage:
        if d.length and d.after_ns is not None and d.before_ns is not None and first <= d.after_ns \
                and d.before_ns <= last:
            d.took_samples = False
    gap = np.flatnonzero(np.diff(s) != 1)
    explained = [(d, d.after_ns, d.before_ns) for d in data.damage]
    for g in gap:
        a, b = int(t[g]), int(t[g + 1])
        hits = [d for d, lo, hi in explained if (lo is None or lo <= b) and (hi is None or hi >= a)]
        if not hits:
            data.damage.append(Damage(0, 0, "frame messages missing (their numbering has a gap) where no "
                                            "damaged record was found", a, b))
        for d in hits:
            if d.length:  # a damaged record: it held these frames
                d.took_samples, d.after_ns, d.before_ns = True, a, b


def _v2_tables(buf: bytes, sizes: list[int], times: list[int]):
    """(offsets, lengths, receive times [ns]) of the frames of consecutive stid.frames.v2
    messages of ``sizes`` bytes in ``buf``, all tables read at once with numpy. A message
    whose table does not add up (impossible in a CRC-checked chunk) is left out whole."""
    arr = np.frombuffer(buf, dtype=np.uint8)
    ends = np.cumsum(np.asarray(sizes, dtype=np.int64))
    pos = ends - np.asarray(sizes, dtype=np.int64)
    ok = np.asarray(sizes, dtype=np.int64) >= 4
    n = np.zeros(len(sizes), np.int64)
    p4 = pos[ok]
    n[ok] = (arr[p4].astype(np.int64) | arr[p4 + 1].astype(np.int64) << 8 | arr[p4 + 2].astype(np.int64) << 16
             | arr[p4 + 3].astype(np.int64) << 24)
    body = pos + 4 + 6 * n
    ok &= body <= ends
    n[~ok] = 0
    mid = np.repeat(np.arange(len(n)), n)  # the message of each frame
    first = np.cumsum(n) - n
    k = np.arange(int(n.sum())) - first[mid]  # the frame's place in its message
    lp = pos[mid] + 4 + 2 * k
    lens = arr[lp].astype(np.int64) | arr[lp + 1].astype(np.int64) << 8
    dp = pos[mid] + 4 + 2 * n[mid] + 4 * k
    dts = (arr[dp].astype(np.int64) | arr[dp + 1].astype(np.int64) << 8 | arr[dp + 2].astype(np.int64) << 16
           | arr[dp + 3].astype(np.int64) << 24)
    before = np.cumsum(lens) - lens  # bytes of frames before this one, over all messages
    offs = body[mid] + before - before[first[mid]] if len(lens) else np.zeros(0, np.int64)
    # each message's frames must fill it exactly
    total = np.zeros(len(n), np.int64)
    np.add.at(total, mid, lens)
    good = ok & (body + total == ends)
    keep = good[mid]
    ns = np.asarray(times, dtype=np.int64)[mid] + 1000 * dts
    return offs[keep], lens[keep], ns[keep]


def _v1_entries(buf: bytes, pos: int, end: int):
    offs, lens = [], []
    while pos + 2 <= end:
        k = buf[pos] | buf[pos + 1] << 8
        if pos + 2 + k > end:
            break
        offs.append(pos + 2)
        lens.append(k)
        pos += 2 + k
    return np.asarray(offs, np.int64), np.asarray(lens, np.int64)


class FrameTable:
    """All logged frames as one byte buffer plus per-frame offset, length and receive time,
    so that the samples of 60k frames are gathered by numpy, not frame by frame."""

    def __init__(self, buf: bytes, offset, length, ns):
        self.buf = buf
        self.arr = np.frombuffer(buf, dtype=np.uint8)
        self.offset = np.asarray(offset, dtype=np.int64)
        self.length = np.asarray(length, dtype=np.int64)
        self.ns = np.asarray(ns, dtype=np.int64)

    @classmethod
    def from_messages(cls, blobs: list[bytes], blob_ns: list[int], v2: bool = True) -> "FrameTable":
        """Frames of /stid/frames messages: stid.frames.v2 (a table of lengths and receive
        offsets, then the frames; see host.mcap_log) or v1 (u16 length + frame, repeated;
        the message's time for all)."""
        buf = b"".join(blobs)
        if not v2:
            offs, lens, nss, pos = [], [], [], 0
            for blob, t in zip(blobs, blob_ns):
                o, k = _v1_entries(buf, pos, pos + len(blob))
                offs.append(o)
                lens.append(k)
                nss.append(np.full(len(o), t, np.int64))
                pos += len(blob)
            cat = (lambda xs: np.concatenate(xs) if xs else np.zeros(0, np.int64))  # noqa: E731
            return cls(buf, cat(offs), cat(lens), cat(nss))
        return cls(buf, *_v2_tables(buf, [len(b) for b in blobs], blob_ns))

    def payload(self, i: int) -> bytes:
        o = int(self.offset[i])
        return self.buf[o:o + int(self.length[i])]

    def byte(self, i, k: int):
        """Byte ``k`` of the frames ``i`` (an index array)."""
        return self.arr[self.offset[i] + k]


def split_frames(blob: bytes, v2: bool = True) -> list[bytes]:
    """The frames of one /stid/frames message (see ``FrameTable.from_messages``)."""
    ft = FrameTable.from_messages([blob], [0], v2)
    return [ft.payload(i) for i in range(len(ft.offset))]


_JSON_TOPICS = {"/stid/hello": "hellos", "/stid/status": "status", "/stid/events": "events"}


def _hellos_from_frames(ft: FrameTable) -> list:
    from host import frame_decoder

    out = []
    compact = getattr(p, "HELLO_COMPACT", None)
    for i in range(len(ft.offset)):
        if ft.length[i] < p.HEADER_SIZE or ft.arr[ft.offset[i] + 1] not in (p.HELLO, compact):
            continue
        pl, ns = ft.payload(i), int(ft.ns[i])
        body = pl[p.HEADER_SIZE:]
        try:
            if pl[1] == compact:
                doc = frame_decoder.decode_compact_hello(body, pl[0])
            else:
                doc = json.loads(body)
                if not isinstance(doc, dict):
                    continue
                norm = getattr(frame_decoder, "normalise_hello", None)
                doc = norm(doc) if norm else doc
        except (ValueError, UnicodeDecodeError):
            continue
        out.append((ns, doc))
    return out


def _json_doc(raw: bytes) -> dict | None:
    try:
        doc = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def _maybe_json(v: str):
    try:
        return json.loads(v)
    except (ValueError, TypeError):
        return v


def _decode_samples(ft: FrameTable):
    """All SAMPLES frames -> (one array, MCU time unwrapped per firmware boot; the number
    of sample frames whose length does not match their count)."""
    head = p.HEADER_SIZE + p.SAMPLES_HEAD_SIZE
    if not len(ft.offset):
        return np.zeros(0, LOADED_DTYPE), 0
    long_enough = ft.length >= head
    idx = np.flatnonzero(long_enough)
    version = ft.byte(idx, 0).astype(np.int64)
    ftype = ft.byte(idx, 1).astype(np.int64)
    is_sample = np.isin(ftype, p.SAMPLE_TYPES)
    idx, version, ftype = idx[is_sample], version[is_sample], ftype[is_sample]
    count = ft.byte(idx, p.HEADER_SIZE + 4).astype(np.int64)
    size = np.zeros(len(idx), np.int64)
    for (ver, typ), rec in p.RECORD_DTYPES.items():
        size[(version == ver) & (ftype == typ)] = rec.itemsize
    ok = (size > 0) & (ft.length[idx] == head + size * count)
    bad = int((~ok).sum())
    idx, version, ftype, count, size = idx[ok], version[ok], ftype[ok], count[ok], size[ok]
    if not len(idx):
        return np.zeros(0, LOADED_DTYPE), bad
    first = sum(ft.byte(idx, p.HEADER_SIZE + k).astype(np.int64) << (8 * k) for k in range(4))
    n = int(count.sum())
    out = np.empty(n, LOADED_DTYPE)  # every field is written below
    sample_at = np.concatenate([[0], np.cumsum(count)[:-1]])
    # runs of one record layout are gathered in one numpy call each
    key = version * 256 + ftype
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(key)) + 1, [len(idx)]])
    for a, b in zip(cuts[:-1], cuts[1:]):
        rec = p.RECORD_DTYPES[(int(version[a]), int(ftype[a]))]
        nbytes = (size[a:b] * count[a:b]).tolist()
        starts = (ft.offset[idx[a:b]] + head).tolist()
        buf = ft.buf
        raw = np.frombuffer(b"".join([buf[o:o + k] for o, k in zip(starts, nbytes)]), dtype=rec)
        lo = int(sample_at[a])
        part = out[lo:lo + len(raw)]
        part[list(rec.names)] = raw  # one structured copy (by position), not a copy per field
        for name in p.SAMPLE_FIELDS:
            if name not in rec.names:
                part[name] = p.FILL[name]
    counts = count
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out["index"] = np.repeat(first, counts) + (np.arange(n) - np.repeat(starts, counts))
    out["index"] %= p.MOD
    out["t_host_ns"] = np.repeat(ft.ns[idx], counts)
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
    return out, bad
