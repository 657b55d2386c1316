"""The host decoder: golden vectors, properties of any input, and fault injection."""

import json
import struct
import zlib

import numpy as np
import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import VECTORS
from host import protocol as p
from host.frame_decoder import FrameDecoder

CASES = json.loads(VECTORS.read_text())["cases"]


def _decode(wire: bytes, step=None):
    dec = FrameDecoder(track_seq=False)
    if step is None:
        frames = dec.feed(wire)
    else:
        frames = [f for i in range(0, len(wire), step) for f in dec.feed(wire[i:i + step])]
    return dec, frames


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
@pytest.mark.parametrize("step", [None, 1, 3, 64])
def test_golden_vectors(case, step):
    dec, frames = _decode(bytes.fromhex(case["wire"]), step)
    got = [(f.payload[1], f.seq, f.t_us, f.body.hex()) for f in frames]  # the type byte as sent
    assert got == [(f["type"], f["seq"], f["t_us"], f["body"]) for f in case["frames"]]
    assert {k: v for k, v in dec.stats.errors.items() if v} == case["errors"]


def test_decoded_meaning_of_vectors():
    for case in CASES:
        for fr, exp in zip(_decode(bytes.fromhex(case["wire"]))[1], case["frames"]):
            if fr.type in p.SAMPLE_TYPES:
                assert fr.version == case["version"]
                arr = fr.samples()
                assert fr.samples_index() == exp["decoded"]["index"]
                for got, want in zip(arr, exp["decoded"]["samples"], strict=True):
                    got = dict(zip(p.SAMPLE_FIELDS, map(int, got)))
                    # the fields this layout carries are as sent, the others read "absent"
                    assert {k: got[k] for k in want} == want
                    absent = {k: got[k] for k in got if k not in want}
                    assert absent == {k: p.FILL[k] for k in absent}
                if case["version"] == 1:
                    assert np.all(arr["steer_t_us"] == p.STEER_T_UNKNOWN)
            elif fr.type == p.STATUS:
                got = fr.status()
                if case["version"] < 3:  # fields version 3 added read None
                    assert got.pop("missed") is None and got.pop("late_max_us") is None
                assert got == exp["decoded"]
            else:
                got = fr.hello()
                assert got.pop("hello") == ("compact" if fr.compact else "full")
                want = dict(exp["decoded"])
                for key in p.HELLO_V3_KEYS:  # keys an older HELLO lacks read None
                    want.setdefault(key, None)
                want.setdefault("sim", False)
                want.setdefault("wheel", want.get("wheels", [None])[0])  # version 3 sends `wheels` only
                assert got == want


def make_frame(seq, n_samples=1, rng=None):
    body = struct.pack("<IB", seq * n_samples % p.MOD, n_samples)
    body += (rng.bytes(22 * n_samples) if rng is not None else bytes(22 * n_samples))
    raw = struct.pack("<BBII", 1, p.SAMPLES, seq % p.MOD, (seq * 2000) % p.MOD) + body
    return raw + struct.pack("<I", zlib.crc32(raw))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=3000), st.lists(st.integers(1, 50), max_size=20))
def test_any_bytes_never_raise(data, cuts):
    dec = FrameDecoder()
    pos = 0
    for c in cuts + [len(data)]:
        dec.feed(data[pos:pos + c])
        pos += c
    assert dec.stats.bytes == min(pos, len(data)) or pos >= len(data)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=60), min_size=1, max_size=8), st.integers(1, 40))
def test_frames_between_garbage_are_all_recovered(garbage, n_frames):
    """Garbage followed by a delimiter never costs a frame that comes after it."""
    rng = np.random.default_rng(n_frames)
    frames = [make_frame(i, 1 + i % 3, rng) for i in range(n_frames)]
    wire = b""
    for i, fr in enumerate(frames):
        wire += garbage[i % len(garbage)] + b"\x00" + cobs.encode(fr) + b"\x00"
    dec = FrameDecoder()
    got = dec.feed(wire)
    assert [f.payload for f in got] == [fr[:-4] for fr in frames]
    assert dec.stats.lost_frames == 0


def test_lost_frames_counted_by_seq_and_restart_detected():
    wire = b"".join(cobs.encode(make_frame(s)) + b"\x00" for s in [0, 1, 2, 5, 6, 10])
    dec = FrameDecoder()
    dec.feed(wire)
    assert dec.stats.lost_frames == 2 + 3
    dec.feed(cobs.encode(make_frame(0)) + b"\x00")  # the firmware rebooted
    assert dec.stats.restarts == 1 and dec.stats.lost_frames == 5


def test_seq_wrap_is_not_a_loss():
    wire = b"".join(cobs.encode(make_frame(s)) + b"\x00" for s in [p.MOD - 2, p.MOD - 1, p.MOD, p.MOD + 1])
    dec = FrameDecoder()
    assert len(dec.feed(wire)) == 4
    assert dec.stats.lost_frames == 0 and dec.stats.restarts == 0


def inject_faults(frames_wire, rng, ber, drop_rate, insert_rate):
    """Corrupt a wire stream. Returns (corrupted bytes, touched mask over the original)."""
    buf = np.frombuffer(frames_wire, dtype=np.uint8).copy()
    n = len(buf)
    touched = np.zeros(n, dtype=bool)
    n_flips = rng.binomial(8 * n, ber)
    bits = rng.integers(0, 8 * n, n_flips)
    np.bitwise_xor.at(buf, bits // 8, (1 << (bits % 8)).astype(np.uint8))
    touched[bits // 8] = True
    drop = rng.random(n) < drop_rate
    touched |= drop
    insert_at = np.flatnonzero(rng.random(n) < insert_rate)
    touched[insert_at] = True  # garbage goes in before these bytes
    pieces = []
    start = 0
    for i in insert_at:
        pieces.append(buf[start:i][~drop[start:i]])
        pieces.append(rng.integers(0, 256, rng.integers(1, 4), dtype=np.uint8))
        start = i
    pieces.append(buf[start:][~drop[start:]])
    return np.concatenate(pieces).tobytes(), touched


@pytest.mark.parametrize("ber,drop,insert,n_frames", [
    (1e-4, 0.0, 0.0, 300_000),
    (1e-3, 0.0, 0.0, 300_000),
    (1e-4, 1e-5, 1e-5, 200_000),
    (1e-3, 1e-4, 1e-4, 200_000),
])
def test_fault_injection(ber, drop, insert, n_frames):
    """Every intact frame recovered, zero corrupt frames accepted, losses counted.

    1,000,000 frames in total across the parameter sets."""
    rng = np.random.default_rng(int(ber * 1e6) + n_frames)
    frames = [make_frame(i, 1, rng) for i in range(n_frames)]
    encoded = [cobs.encode(f) + b"\x00" for f in frames]
    ends = np.cumsum([len(e) for e in encoded]) - 1  # index of each frame's delimiter
    wire, touched = inject_faults(b"".join(encoded), rng, ber, drop, insert)
    dec = FrameDecoder()
    got = []
    for i in range(0, len(wire), 4096):  # as a serial port delivers it
        got += dec.feed(wire[i:i + 4096])
    by_seq = {}
    for f in got:
        assert f.payload == frames[f.seq][:-4], "a corrupt frame was accepted"
        by_seq[f.seq] = f
    # intact: no byte touched from the previous delimiter to this frame's delimiter
    prefix = np.concatenate([[0], np.cumsum(touched)])
    starts = np.concatenate([[0], ends[:-1]])
    intact = (prefix[ends + 1] - prefix[starts]) == 0
    missing = [i for i in np.flatnonzero(intact) if i not in by_seq]
    assert not missing, f"{len(missing)} intact frames lost, e.g. seq {missing[:5]}"
    seqs = sorted(by_seq)
    assert dec.stats.lost_frames == (seqs[-1] - seqs[0] + 1) - len(seqs)
    assert dec.stats.rejected > 0 and intact.sum() < n_frames  # the faults did happen
