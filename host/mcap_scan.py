"""Walk an MCAP file record by record, trusting nothing that a checksum does not cover.

The official readers stop at the first bad byte (or, without ``validate_crcs``, hand
back wrong values). A logged run must give back everything that is intact and say
exactly what is not, so this walker:

- checks every chunk's CRC (``uncompressed_crc``, CRC-32 of the decompressed records,
  as the MCAP spec defines and ``mcap``'s ``validate_crcs=True`` checks) before
  believing a single byte of it; a chunk that fails is skipped and reported;
- bounds every length before allocating (a flipped size field must not ask for
  exabytes);
- after a damaged record, resynchronises at the next record that parses (a chunk,
  a metadata record or the data end), so one flipped bit costs one chunk, not the
  rest of the file;
- tells a file cut short (no data end, nothing intact after the cut) from one
  damaged in the middle.

Records outside chunks (metadata, indexes) carry no CRC of their own; the data
section CRC (written by ``McapLog``) covers them, and a mismatch is reported.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Header, Metadata, Schema

MAGIC = b"\x89MCAP0\r\n"
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
MESSAGE_INDEX, METADATA, DATA_END = 0x07, 0x0C, 0x0F
OWN_CHUNKS_KEY = "stid.chunks"  # channel metadata "own": its messages never share a chunk (host.mcap_log)

MAX_CHUNK = 256 * 1024 * 1024  # no chunk of ours decompresses beyond this: a bigger size is damage

_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


def holds_a_log(path) -> bool:
    """Whether ``path`` is an MCAP file (a recorded run, which nothing of stid overwrites). Only a
    regular file can be one: reading a pipe or a terminal to find out (``--csv /dev/stdout``)
    waited for its writer, for ever."""
    if not os.path.isfile(path):
        return False
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


# every chunk starts with its header fields, then the compression name: resync on that name
_RESYNC = [(b"\x04\x00\x00\x00zstd", 8 + 8 + 8 + 4), (b"\x03\x00\x00\x00lz4", 8 + 8 + 8 + 4)]
_DATA_END = b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00"


@dataclass(slots=True)
class RawMessage:
    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


@dataclass
class Damage:
    """A stretch of the file that could not be trusted and was skipped."""

    offset: int  # bytes from the start of the file
    length: int
    reason: str
    after_ns: int | None = None  # log time of the last intact message before it
    before_ns: int | None = None  # ... and of the first after it
    took_samples: bool | None = None  # frames lost with it (host.mcap_read; None: cannot tell)

    def as_dict(self) -> dict:
        return {"offset": self.offset, "length": self.length, "reason": self.reason,
                "after_ns": self.after_ns, "before_ns": self.before_ns}


@dataclass
class Scan:
    header: Header | None = None
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)  # RawMessage, in file order
    metadata: list = field(default_factory=list)  # Metadata records, in file order
    damage: list = field(default_factory=list)  # Damage
    truncated: bool = False  # the data section ends before its end record: the writer was stopped
    finished: bool = False  # the file ends with the closing magic (the writer finished it)
    data_crc_ok: bool | None = None  # None: not checked (cut short, or written without it)
    chunks: int = 0
    chunk_spans: list = field(default_factory=list)  # (offset, first log time, last log time) of good chunks
    skipped_messages: int = 0  # on channels the caller did not want
    own_chunk_ids: set = field(default_factory=set)  # skipped channels written in chunks of their own

    @property
    def lost_bytes(self) -> int:
        return sum(d.length for d in self.damage)


class _Bad(Exception):
    """A record that does not parse or fails its checksum (message: why)."""


def scan(buf: bytes, skip_topics=frozenset(), chunks: dict | None = None) -> Scan:
    """Every trustworthy record of an MCAP file held in ``buf`` (which starts with the magic).

    Messages on ``skip_topics`` are not copied out (loading speed), but still counted.
    ``chunks``: what earlier scans of the same file found in its chunks, kept by the caller
    for a file that grows (``stid live`` rereads a log every few seconds while stid-log
    appends to it): a chunk at the same place with the same length and CRC is taken from it
    instead of being decompressed and checked again, and new chunks are added to it.
    """
    out = Scan()
    view = memoryview(buf)
    n = len(buf)
    skip_ids: set[int] = set()
    pos = len(MAGIC)
    bad_from: int | None = None  # start of the damaged stretch we are resyncing across
    bad_why = ""
    while pos < n:
        try:
            op, length = _REC.unpack_from(buf, pos)
        except struct.error:
            op, length = -1, 0
        end = pos + 9 + length
        try:
            if op < 0 or end > n:
                raise _Bad("a record runs past the end of the file")
            if op == CHUNK:
                lo, hi = (_chunk(view[pos + 9:end], out, skip_ids, skip_topics) if chunks is None
                          else _remembered_chunk(buf, pos, end, out, skip_ids, skip_topics, chunks))
                out.chunks += 1
                if lo is not None:
                    out.chunk_spans.append((pos, lo, hi))
            elif op == METADATA:
                out.metadata.append(_exact(Metadata, view[pos + 9:end]))
            elif op == HEADER:
                out.header = _exact(Header, view[pos + 9:end])
            elif op in (SCHEMA, CHANNEL):
                _add_def(_exact(Schema if op == SCHEMA else Channel, view[pos + 9:end]), out, skip_ids,
                         skip_topics)
            elif op == DATA_END:
                if length != 4:
                    raise _Bad("a damaged data end record")
                if bad_from is not None:
                    out.damage.append(Damage(bad_from, pos - bad_from, bad_why))
                    bad_from = None
                crc = struct.unpack_from("<I", buf, pos + 9)[0]
                if crc:
                    out.data_crc_ok = zlib.crc32(view[:pos]) == crc
                _summary(buf, end, out, skip_ids, skip_topics)
                break
            elif op == MESSAGE_INDEX:
                # not needed to read the data, but it must be one: a damaged opcode must not
                # make a chunk look like an index to be skipped
                if length < 6 or struct.unpack_from("<I", buf, pos + 11)[0] != length - 6 or (length - 6) % 16:
                    raise _Bad("a damaged message index record")
            else:
                raise _Bad("a record that does not belong in the data section (damaged record header)")
        except _Bad as e:
            if bad_from is None:
                bad_from, bad_why = pos, str(e)
            pos = _resync(buf, pos + 1)
            continue
        if bad_from is not None:
            out.damage.append(Damage(bad_from, pos - bad_from, bad_why))
            bad_from = None
        pos = end
    else:
        out.truncated = True
        if bad_from is not None:
            out.damage.append(Damage(bad_from, n - bad_from, bad_why))
    out.finished = buf.endswith(MAGIC) and n >= 2 * len(MAGIC)
    if out.truncated and out.finished:
        # the closing magic is there: the writer finished, and the end is damaged, not cut
        out.truncated = False
        if not out.damage:
            out.damage.append(Damage(n, 0, "the data end record is missing"))
    _place_damage(out)
    return out


def _remembered_chunk(buf: bytes, pos: int, end: int, out: Scan, skip_ids: set, skip_topics, chunks: dict):
    """``_chunk``, or what it gave for the same chunk before: the messages it added, the
    definitions it held, the messages it skipped (replayed in that order)."""
    body = memoryview(buf)[pos + 9:end]
    try:
        key = (pos, end, _CHUNK_HEAD.unpack_from(body, 0)[2:4])  # place, end, size and CRC
    except struct.error:
        key = None
    known = chunks.get(key) if key is not None else None
    if known is not None:
        lo, hi, defs, messages, skipped = known
        for rec in defs:
            _add_def(rec, out, skip_ids, skip_topics)
        out.messages.extend(messages)
        out.skipped_messages += skipped
        return lo, hi
    n_msg, n_skip = len(out.messages), out.skipped_messages
    channels, schemas = set(out.channels), set(out.schemas)
    lo, hi = _chunk(body, out, skip_ids, skip_topics)
    if key is not None:
        defs = [out.schemas[i] for i in out.schemas if i not in schemas]
        defs += [out.channels[i] for i in out.channels if i not in channels]
        chunks[key] = (lo, hi, defs, out.messages[n_msg:], out.skipped_messages - n_skip)
    return lo, hi


def _exact(cls, body: memoryview):
    """Parse one record with mcap's own reader; it must use exactly its stated length."""
    stream = ReadDataStream(BytesIO(body))
    try:
        rec = cls.read(stream)
    except Exception as e:  # noqa: BLE001 - any parse failure of a damaged record (struct, utf-8, EOF)
        raise _Bad(f"a damaged {cls.__name__.lower()} record ({type(e).__name__})") from None
    if stream.count != len(body):
        raise _Bad(f"a damaged {cls.__name__.lower()} record (length mismatch)")
    return rec


def _add_def(rec, out: Scan, skip_ids: set, skip_topics) -> None:
    if isinstance(rec, Schema):
        out.schemas.setdefault(rec.id, rec)
    elif rec.id not in out.channels:
        out.channels[rec.id] = rec
        if rec.topic in skip_topics:
            skip_ids.add(rec.id)
            # the claim holds only in a file stid-log itself wrote: another writer that copies the
            # channel (the mcap library, `stid repair`) keeps the tag but mixes channels in its
            # chunks, and trusting it there dropped whole chunks of samples unreported
            header = out.header
            if rec.metadata.get(OWN_CHUNKS_KEY) == "own" and header is not None and header.library == "stid-log":
                out.own_chunk_ids.add(rec.id)


def _chunk(body: memoryview, out: Scan, skip_ids: set, skip_topics) -> None:
    try:
        _start, _end, usize, crc, clen = _CHUNK_HEAD.unpack_from(body, 0)
        comp = bytes(body[32:32 + clen]).decode("ascii")
        (dlen,) = struct.unpack_from("<Q", body, 32 + clen)
    except (struct.error, UnicodeDecodeError):
        raise _Bad("a damaged chunk header") from None
    head = 32 + clen + 8
    if head + dlen != len(body):
        raise _Bad("a damaged chunk header (length mismatch)")
    if usize > MAX_CHUNK:
        raise _Bad("a damaged chunk header (impossible size)")
    data = body[head:]
    if comp == "zstd":
        try:
            # the frame declares its own size, which damage can make any number: the
            # decompressor would allocate it (a MemoryError at petabytes). It must be the chunk's.
            declared = zstandard.frame_content_size(data)
            if declared not in (-1, usize):
                raise _Bad("a chunk that does not decompress (its frame's size differs from the chunk's)")
            data = zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
        except (zstandard.ZstdError, MemoryError):
            raise _Bad("a chunk that does not decompress") from None
    elif comp == "lz4":
        import lz4.frame  # optional, as in mcap itself

        try:
            data = lz4.frame.decompress(bytes(data))
        except RuntimeError:
            raise _Bad("a chunk that does not decompress") from None
    elif comp != "":
        raise _Bad(f"a chunk with unknown compression {comp[:10]!r}")
    if len(data) != usize or (crc and zlib.crc32(data) != crc):
        raise _Bad("a chunk whose CRC does not match its contents")
    if not crc:
        raise _Bad("a chunk without a CRC (cannot be trusted)")
    return _records(data, out, skip_ids, skip_topics)


def _records(data, out: Scan, skip_ids: set, skip_topics) -> None:
    """The records of a chunk that passed its CRC: what the writer wrote.
    Returns the first and last log time in it."""
    pos, n = 0, len(data)
    lo = hi = None
    unpack, msg = _REC.unpack_from, _MSG.unpack_from
    if n >= 11 and data[0] == MESSAGE and (data[9] | data[10] << 8) in out.own_chunk_ids:
        return lo, hi  # a chunk of a skipped channel that never shares its chunks: nothing to read
    append = out.messages.append
    try:
        while pos < n:
            op, length = unpack(data, pos)
            body, end = pos + 9, pos + 9 + length
            if end > n:
                raise _Bad("a chunk whose records overrun it")
            if op == MESSAGE:
                chid, seq, log_t, pub_t = msg(data, body)
                if lo is None or log_t < lo:
                    lo = log_t
                if hi is None or log_t > hi:
                    hi = log_t
                if chid in skip_ids:
                    out.skipped_messages += 1
                else:
                    append(RawMessage(chid, seq, log_t, pub_t, data[body + 22:end]))
            elif op == CHANNEL:
                _add_def(_exact(Channel, memoryview(data)[body:end]), out, skip_ids, skip_topics)
            elif op == SCHEMA:
                _add_def(_exact(Schema, memoryview(data)[body:end]), out, skip_ids, skip_topics)
            pos = end
    except struct.error:
        raise _Bad("a chunk whose records overrun it") from None
    return lo, hi


def _resync(buf: bytes, start: int) -> int:
    """The next place at or after ``start`` where a chunk, metadata or data end may begin."""
    best = len(buf)
    for marker, before in _RESYNC:
        k = buf.find(marker, start + before)
        while k >= 0 and k - before - 9 < start:
            k = buf.find(marker, k + 1)
        if k >= 0 and buf[k - before - 9] == CHUNK:
            best = min(best, k - before - 9)
    k = buf.find(b"stid.", start)
    while 0 <= k < best:
        # metadata: opcode, length, name length, name (ours all start with "stid.")
        at = k - 13
        if at >= start and buf[at] == METADATA:
            best = min(best, at)
            break
        k = buf.find(b"stid.", k + 1)
    k = buf.find(_DATA_END, start)
    if k >= 0:
        best = min(best, k)
    return best


def _summary(buf: bytes, pos: int, out: Scan, skip_ids: set, skip_topics) -> None:
    """Channel and schema definitions from the summary (only if its CRC holds): they
    name the channels of messages whose own definitions were in a damaged chunk."""
    n = len(buf)
    foot = n - len(MAGIC) - 29
    if foot < pos or buf[foot] != FOOTER:
        return
    start, _offsets, crc = struct.unpack_from("<QQI", buf, foot + 9)
    if not start or not crc or not pos <= start <= foot or zlib.crc32(buf[start:foot + 25]) != crc:
        return
    k = start
    try:
        while k < foot:
            op, length = _REC.unpack_from(buf, k)
            end = k + 9 + length
            if end > foot:
                return
            if op == SCHEMA:
                rec = _exact(Schema, memoryview(buf)[k + 9:end])
                out.schemas.setdefault(rec.id, rec)
            elif op == CHANNEL:
                rec = _exact(Channel, memoryview(buf)[k + 9:end])
                if rec.id not in out.channels:
                    out.channels[rec.id] = rec
                    if rec.topic in skip_topics:
                        skip_ids.add(rec.id)
            k = end
    except (_Bad, struct.error):
        return


def _place_damage(out: Scan) -> None:
    """Say when each damaged stretch was: between the log times of its intact neighbours."""
    for d in out.damage:
        before = [hi for off, _lo, hi in out.chunk_spans if off < d.offset]
        after = [lo for off, lo, _hi in out.chunk_spans if off > d.offset]
        d.after_ns = max(before) if before else None
        d.before_ns = min(after) if after else None
