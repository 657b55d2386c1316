"""A topic's raw messages as arrays of the fields asked for.

``rosbags`` deserialises one message at a time into Python objects: ~35 us per IMU
message, 6 s for a 10-minute bag of 180,000 messages. The fields a run needs sit at
the same byte offsets in every message of a topic as long as its strings and
sequences keep their lengths (a frame_id does not change), so the offsets are found
once, from the message definition and the first message, and each field is read for
all messages at once with numpy. The library still decodes the first and the last
message, and the two must agree; a topic whose layout changes from message to message
is decoded by the library, message by message.
"""

from __future__ import annotations

import numpy as np

from stid.errors import InputError

_SIZE = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
         "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8}
_KIND = {"bool": "u", "byte": "u", "char": "u", "uint8": "u", "uint16": "u", "uint32": "u", "uint64": "u",
         "int8": "i", "int16": "i", "int32": "i", "int64": "i", "float32": "f", "float64": "f"}


class _Varies(Exception):
    """The layout cannot be read from one message (unsupported construct)."""


class _Layout:
    """Where each scalar field of one message sits, and the length words that fix it."""

    def __init__(self, typestore, cdr: bool, raw: bytes):
        self.ts, self.cdr, self.raw = typestore, cdr, raw
        self.little = (raw[1] == 1) if cdr else True
        self.base = 4 if cdr else 0  # CDR aligns relative to the data after its 4-byte encapsulation header
        self.leaves: dict[str, tuple[int, str]] = {}
        self.length_words: list[int] = []

    def _align(self, pos: int, size: int) -> int:
        if not self.cdr or size <= 1:
            return pos
        rel = pos - self.base
        return self.base + ((rel + size - 1) // size) * size

    def _u32(self, pos: int) -> int:
        return int.from_bytes(self.raw[pos:pos + 4], "little" if self.little else "big")

    def walk(self, typename: str, pos: int, prefix: str) -> int:
        fields = self.ts.fielddefs[typename][1]
        if not fields:
            raise _Varies(f"{typename} has no fields")
        for name, desc in fields:
            pos = self._field(desc, pos, prefix + name)
        return pos

    def _field(self, desc, pos: int, path: str) -> int:
        node, what = desc[0], desc[1]
        kind = getattr(node, "name", str(node))
        if kind == "BASE":
            typ = what[0]
            if typ == "string" or typ == "wstring":
                return self._string(pos)
            pos = self._align(pos, _SIZE[typ])
            self.leaves[path] = (pos, typ)
            return pos + _SIZE[typ]
        if kind == "NAME":
            return self.walk(what, pos, path + ".")
        if kind == "ARRAY":
            sub, count = what
            for k in range(count):
                pos = self._field(sub, pos, f"{path}[{k}]")
            return pos
        if kind == "SEQUENCE":
            sub = what[0]
            pos = self._align(pos, 4)
            self.length_words.append(pos)
            count = self._u32(pos)
            pos += 4
            for k in range(count):
                pos = self._field(sub, pos, f"{path}[{k}]")
            return pos
        raise _Varies(f"field kind {kind}")

    def _string(self, pos: int) -> int:
        pos = self._align(pos, 4)
        self.length_words.append(pos)
        return pos + 4 + self._u32(pos)


class Rows:
    """Messages of one serialised length lying in a byte buffer: ``raw[start:start + width]``
    each. Only the bytes a field needs are ever gathered."""

    def __init__(self, raw: np.ndarray, starts: np.ndarray, width: int):
        self.raw, self.starts, self.width = raw, starts, int(width)

    def __len__(self) -> int:
        return len(self.starts)

    def columns(self, offset: int, size: int) -> np.ndarray:
        """The bytes ``offset:offset + size`` of every message, as an (n, size) array."""
        return self.raw[self.starts[:, None] + (offset + np.arange(size))]

    def row(self, k: int) -> bytes:
        return self.raw[self.starts[k]:self.starts[k] + self.width].tobytes()


def as_rows(raws: list) -> list:
    """Serialised messages (bytes) as Rows, one per run of equal lengths."""
    if not raws:
        return []
    lengths = np.fromiter(map(len, raws), np.int64, len(raws))
    if np.all(lengths == lengths[0]):
        return [Rows(np.frombuffer(b"".join(raws), np.uint8), np.arange(len(raws)) * int(lengths[0]),
                     int(lengths[0]))]
    return [Rows(np.frombuffer(bytes(r), np.uint8), np.zeros(1, np.int64), len(r)) for r in raws]


def read_fields(blocks: list, typestore, typename: str, fields: list[str], cdr: bool, topic: str,
                order=None) -> dict:
    """``{field: array}`` over all messages of a topic.

    Parameters
    ----------
    blocks : list of Rows
        The serialised messages (CDR for ROS 2, ROS 1 serialisation otherwise), in file order
        (``as_rows`` makes them from bytes).
    typestore : rosbags Typestore
        Holds ``typename``'s definition (from the bag).
    fields : list of str
        Dotted paths of scalar fields, e.g. ``"linear_acceleration.x"``, ``"header.stamp.sec"``.
    order : int array or None
        The messages' order in time, when the file order is not.
    """
    n = sum(len(b) for b in blocks)
    if n == 0:
        return {f: np.zeros(0) for f in fields}
    first, last = blocks[0].row(0), blocks[-1].row(len(blocks[-1]) - 1)
    if len({b.width for b in blocks}) == 1:
        try:
            out = _vectorised(blocks, first, typestore, typename, fields, cdr)
        except _Varies:
            out = None
        if out is not None and all(_agrees(out, k, raw, typestore, typename, fields, cdr)
                                   for k, raw in ((0, first), (n - 1, last))):
            return out if order is None else {f: v[order] for f, v in out.items()}
    raws = [b.row(k) for b in blocks for k in range(len(b))]
    if order is not None:
        raws = [raws[k] for k in order]
    return _one_by_one(raws, typestore, typename, fields, cdr, topic)


def _vectorised(blocks, first: bytes, typestore, typename, fields, cdr):
    layout = _Layout(typestore, cdr, first)
    layout.walk(typename, layout.base, "")
    missing = [f for f in fields if f not in layout.leaves]
    if missing:
        raise _Varies(f"no scalar field {missing[0]}")
    gather = lambda off, size: np.vstack([b.columns(off, size) for b in blocks])  # noqa: E731
    # the layout holds for every message whose length words (and encapsulation) are the first's
    fixed = [(0, 4)] if cdr else []
    fixed += [(w, 4) for w in layout.length_words]
    for off, size in fixed:
        if np.any(gather(off, size) != np.frombuffer(first[off:off + size], np.uint8)):
            return None
    order = "<" if layout.little else ">"
    out = {}
    for f in fields:
        off, typ = layout.leaves[f]
        size = _SIZE[typ]
        dtype = np.dtype(f"{order}{_KIND[typ]}{size}")
        out[f] = np.ascontiguousarray(gather(off, size)).view(dtype).ravel().astype(float)
    return out


def _value(msg, path: str) -> float:
    for part in path.split("."):
        msg = getattr(msg, part)
    return float(msg)


def _decode(raw, typestore, typename, cdr):
    return typestore.deserialize_cdr(raw, typename) if cdr else typestore.deserialize_ros1(raw, typename)


def _agrees(out, k, raw, typestore, typename, fields, cdr) -> bool:
    msg = _decode(raw, typestore, typename, cdr)
    return all(_value(msg, f) == out[f][k] or (np.isnan(out[f][k]) and np.isnan(_value(msg, f))) for f in fields)


def _one_by_one(raws, typestore, typename, fields, cdr, topic) -> dict:
    out = {f: np.empty(len(raws)) for f in fields}
    for k, raw in enumerate(raws):
        try:
            msg = _decode(raw, typestore, typename, cdr)
        except Exception as e:  # noqa: BLE001 - any decode failure of a damaged message
            raise InputError(f"topic {topic}: message {k + 1} of {len(raws)} does not decode as {typename} "
                             f"({e}); the bag is damaged there") from None
        for f in fields:
            out[f][k] = _value(msg, f)
    return out
