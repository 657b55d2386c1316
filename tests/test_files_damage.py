"""Files that cannot lie: a damaged log gives back only what is intact, says what is
not, and never raises a traceback.

The log here is written in the test itself from plain physics (a car on a 2 m
circle at 3 m/s: ay = v^2/R, r = v/R, through the ADXL335/LISY300AL datasheet
scales), framed by hand per firmware/PROTOCOL.md, and recorded by the logger's
recorder. Then it is damaged more than a thousand ways.
"""

from __future__ import annotations

import json
import struct
import subprocess
import zlib

import numpy as np
import pytest
from cobs import cobs

from conftest import tool
from host.errors import HostError
from host.mcap_log import McapLog
from host.mcap_read import LogReadError, read_log
from host.recorder import Recorder

RATE = 500  # Hz
V, RADIUS = 3.0, 2.0  # m/s, m
VREF, BITS = 3.3, 12
G = 9.81
T0_NS = 1_700_000_000_000_000_000


def _frame(ftype: int, seq: int, t_us: int, body: bytes, version: int = 2) -> bytes:
    raw = struct.pack("<BBII", version, ftype, seq, t_us) + body
    return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"


def hello_doc(uid: str | None = "e66038b713254a2f", boot_id: str = "0badcafe") -> dict:
    doc = {"proto": 2, "fw": "test", "board": "pico", "boot_id": boot_id, "rate_hz": RATE, "batch": 10,
           "mod": 1 << 30, "adc": {"bits": BITS, "vref": VREF, "unit": "count"},
           "wheel": {"pin": 2, "pulses_per_rev": 1, "wheel": "rl"},
           "wheels": [{"pin": 2, "pulses_per_rev": 1, "wheel": "rl"}]}
    if uid is not None:
        doc["uid"] = uid
    return doc


def counts_for(ay: float, r: float) -> tuple[int, int]:
    """Datasheet inverse: ADXL335 Vs/2 + Vs/10 per g; LISY300AL 1.65 V + 3.3 mV/(deg/s)."""
    full = (1 << BITS) - 1
    v_ay = VREF * (0.5 + ay / (10 * G))
    v_r = 1.65 + np.degrees(r) * 3.3e-3
    return int(round(v_ay / VREF * full)), int(round(v_r / VREF * full))


def circle_stream(seconds: float, hello_every_s: float | None = 1.0, uid="e66038b713254a2f",
                  version: int = 2, batch: int = 10, boot_id: str = "0badcafe") -> bytes:
    """Protocol frames of a car on a circle: SAMPLES (v2, 26-byte records) + HELLO."""
    ay_c, r_c = counts_for(V * V / RADIUS, V / RADIUS)
    zero_c, _ = counts_for(0.0, 0.0)
    n = int(seconds * RATE)
    out = bytearray()
    seq = 0
    doc = json.dumps(hello_doc(uid, boot_id), separators=(",", ":")).encode()
    next_hello = 0.0
    for i0 in range(0, n, batch):
        t_s = i0 / RATE
        if hello_every_s is not None and t_s >= next_hello:
            out += _frame(1, seq, int(t_s * 1e6), doc, version)
            seq += 1
            next_hello += hello_every_s
        recs = bytearray()
        k = min(batch, n - i0)
        for i in range(i0, i0 + k):
            t_us = i * (1_000_000 // RATE)
            recs += struct.pack("<IHHHHHHIHI", t_us, zero_c, ay_c, 0xFFFF, r_c, 1500, 0, 0, 0xFFFF, t_us)
        out += _frame(2, seq, (i0 + k) * (1_000_000 // RATE), struct.pack("<IB", i0, k) + bytes(recs), version)
        seq += 1
    return bytes(out)


def record(stream: bytes, path, chunk_size: int = 256 * 1024, read_size: int = 300, supplied=None,
           flush_s: float | None = None):
    """Through the logger's recorder; each read arrives 2 ms (USB latency) after the MCU
    time of the last frame it completes, as on a real port. ``flush_s``: flush every so many
    seconds of the stream, as stid-log does every second (the per-sample view's chunks then
    sit between the frames' chunks, not after them)."""
    log = McapLog(path, fsync=False, chunk_size=chunk_size)
    rec = Recorder(log)
    rec.event("connect", T0_NS, "test")
    ends, times = [], []
    pos = 0
    for part in stream.split(b"\x00")[:-1]:
        pos += len(part) + 1
        try:
            t_us = struct.unpack_from("<I", cobs.decode(part), 6)[0]
        except (cobs.DecodeError, struct.error):
            continue  # a damaged frame: the next good one dates the read
        ends.append(pos)
        times.append(t_us)
    ends = np.asarray(ends)
    flushed_us = times[0] if times else 0
    for i in range(0, len(stream), read_size):
        chunk = stream[i:i + read_size]
        k = np.searchsorted(ends, i + len(chunk), side="right") - 1
        t_us = times[k] if k >= 0 else 0
        rec.feed(chunk, T0_NS + t_us * 1000 + 2_000_000)
        if flush_s is not None and t_us >= flushed_us + flush_s * 1e6:
            log.flush()
            flushed_us = t_us
    if supplied is not None:
        rec.supply_hello(*supplied)
    stats = rec.finish(T0_NS + 10**10)
    log.close()
    return stats


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """3 s on the circle, many small chunks (so damage hits one chunk, not all)."""
    path = tmp_path_factory.mktemp("dmg") / "run.mcap"
    record(circle_stream(3.0), path, chunk_size=2048)
    return path


def test_undamaged_log_reads_the_physics(small_log):
    log = read_log(small_log)
    assert not log.damage and not log.truncated and log.data_crc_ok
    s = log.samples
    assert len(s) == 3 * RATE
    assert np.array_equal(s["index"], np.arange(len(s)))
    from host import units

    ay = units.accel_si(s["ay"], log.hello)
    r = units.yaw_rate_si(s["yaw"], log.hello)
    # within one ADC count of the circle's v^2/R and v/R
    assert np.allclose(ay, V * V / RADIUS, atol=10 * G * VREF / VREF / 4095 * 1.01)
    assert np.allclose(r, V / RADIUS, atol=np.radians(VREF / 4095 / 3.3e-3) * 1.01)


def _damaged(buf: bytes, rng, kind: str) -> bytes:
    b = bytearray(buf)
    n = len(b)
    if kind == "flip":
        k = int(rng.integers(0, n * 8))
        b[k // 8] ^= 1 << (k % 8)
    elif kind == "flips":
        for k in rng.integers(0, n * 8, 8):
            b[k // 8] ^= 1 << (k % 8)
    elif kind == "truncate":
        return bytes(b[:int(rng.integers(1, n))])
    elif kind == "zero_block":
        a = int(rng.integers(0, n - 1))
        ln = int(rng.integers(1, 600))
        b[a:a + ln] = bytes(min(ln, n - a))
    elif kind == "bytes":
        a = int(rng.integers(0, n - 1))
        ln = int(rng.integers(1, 40))
        b[a:a + ln] = rng.integers(0, 256, min(ln, n - a), dtype=np.uint8).tobytes()
    return bytes(b)


KINDS = ("flip", "flip", "flip", "flips", "truncate", "zero_block", "bytes")


def test_a_thousand_damaged_files_never_lie(small_log, tmp_path):
    """Bit flips, truncations, zeroed blocks, random bytes: never a traceback, and every
    sample read back is one of the undamaged file's, with exactly its values."""
    good = read_log(small_log).samples
    by_index = {int(i): k for k, i in enumerate(good["index"])}
    buf = small_log.read_bytes()
    rng = np.random.default_rng(12)
    path = tmp_path / "bad.mcap"
    outcomes = {"intact": 0, "damaged": 0, "truncated": 0, "refused": 0}
    variants = 1050
    for v in range(variants):
        kind = KINDS[v % len(KINDS)]
        path.write_bytes(_damaged(buf, rng, kind))
        try:
            log = read_log(path)
        except HostError:
            outcomes["refused"] += 1
            continue
        s = log.samples
        if len(s):
            rows = np.fromiter((by_index.get(int(i), -1) for i in s["index"]), dtype=np.int64, count=len(s))
            assert (rows >= 0).all(), f"variant {v} ({kind}): a sample index the file never had"
            for name in ("ax", "ay", "az", "yaw", "steer_us", "t_us", "t_mcu_us", "t_host_ns", "steer_t_us"):
                assert np.array_equal(s[name], good[name][rows]), f"variant {v} ({kind}): {name} differs"
        if v % 25 == 0:  # repair copes with the same damage and keeps exactly what was intact
            from host.repair import repair

            fixed = tmp_path / "fixed.mcap"
            fixed.unlink(missing_ok=True)  # (repair never replaces a run)
            try:
                repair(path, fixed)
            except HostError:
                assert not len(s)
            else:
                again = read_log(fixed)
                assert np.array_equal(again.samples, s) and not again.truncated
                assert bool(again.damage) == bool(log.damage)  # what the original lacked is still said
        lost = len(s) < len(good)
        if lost:
            # anything missing is said: damage or a cut, never silence
            assert log.damage or log.truncated, f"variant {v} ({kind}): samples lost without a word"
        outcomes["truncated" if log.truncated else "damaged" if log.damage else "intact"] += 1
    assert sum(outcomes.values()) == variants
    assert outcomes["damaged"] > 100 and outcomes["truncated"] > 50  # the damage really happened


def test_a_chunk_whose_frame_claims_a_petabyte_is_damage_not_a_memory_error():
    """Damage to a zstd frame's header can make it declare any content size; the decompressor
    allocates what the frame declares: a MemoryError escaped the reader (found when the
    thousand damaged files above happened to hit it). The frame's size must be the chunk's."""
    from host.mcap_scan import MAX_CHUNK, Scan, _Bad, _chunk

    # a zstd frame: magic, a descriptor for an 8-byte content size in a single segment, 2^50,
    # then one empty raw block
    frame = b"\x28\xb5\x2f\xfd" + bytes([0xE0]) + struct.pack("<Q", 1 << 50) + b"\x01\x00\x00"
    usize = 1000
    assert usize < MAX_CHUNK
    body = struct.pack("<QQQII", 0, 1, usize, 0, 4) + b"zstd" + struct.pack("<Q", len(frame)) + frame
    with pytest.raises(_Bad, match="does not decompress"):
        _chunk(memoryview(body), Scan(), set(), frozenset())


def test_foreign_mcap_is_refused_in_one_line(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="someone")
        sid = w.register_schema("x", "jsonschema", b"{}")
        ch = w.register_channel("/camera", "json", sid)
        w.add_message(ch, 1, b"{}", 1)
        w.finish()
    with pytest.raises(LogReadError, match="not a stid log"):
        read_log(path)


def test_one_damaged_chunk_is_reported_with_its_time(small_log, tmp_path):
    clean = small_log.read_bytes()
    n_good = len(read_log(small_log).samples)
    chunks, k = [], clean.find(b"\x04\x00\x00\x00zstd")
    while k >= 0:
        chunks.append(k)
        k = clean.find(b"\x04\x00\x00\x00zstd", k + 1)
    path = tmp_path / "one.mcap"

    def damage(at):
        buf = bytearray(clean)
        buf[at + 40] ^= 0x10  # inside its compressed data
        path.write_bytes(bytes(buf))
        return read_log(path)

    # the chunks that hold samples (the per-sample view's own chunks come later); the middle one
    holding = [c for c in chunks if len(damage(c).samples) < n_good]
    log = damage(holding[len(holding) // 2])
    assert len(log.damage) == 1 and not log.truncated
    d = log.damage[0]
    assert d.after_ns is not None and d.before_ns is not None and d.after_ns <= d.before_ns
    # its place holds the samples it took (chunks of other channels interleave with the samples'
    # by time: the damaged chunk's neighbours in the file do not bound it)
    clean_t = read_log(small_log).samples["t_host_ns"]
    lost = np.setdiff1d(clean_t, log.samples["t_host_ns"])
    assert len(lost) and d.after_ns <= lost.min() and lost.max() <= d.before_ns, \
        (d.after_ns - lost.min(), lost.max() - d.before_ns)
    note = log.damage_note()
    assert "skipped" in note and "bytes" in note
    # the official reader with validate_crcs agrees that the file is damaged
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        with pytest.raises(Exception):
            for _ in make_reader(f, validate_crcs=True).iter_messages():
                pass


def test_damage_is_placed_where_its_samples_were_and_damage_to_other_channels_loses_none(tmp_path):
    """A log as stid-log writes it: flushed every second, so each second's per-sample view
    (/stid/samples, for Foxglove) sits in a chunk of its own between the frames' chunks. The
    samples stid reads come from the frames. Damage to a frames chunk is placed in time where
    the samples it took were (its neighbours in the file hold the view of the same seconds, and
    do not bound it); damage to a view chunk takes no sample, and the note must not say it did."""
    from mcap.reader import make_reader

    clean_path = tmp_path / "run.mcap"
    record(circle_stream(6.0), clean_path, flush_s=1.0)
    clean = clean_path.read_bytes()
    clean_t = read_log(clean_path).samples["t_host_ns"]
    with open(clean_path, "rb") as f:
        summary = make_reader(f).get_summary()
    topic = {c.id: c.topic for c in summary.channels.values()}
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    frames = [c for c in chunks if "/stid/frames" in {topic[k] for k in c.message_index_offsets}]
    view = [c for c in chunks if {topic[k] for k in c.message_index_offsets} == {"/stid/samples"}]
    assert len(frames) > 4 and len(view) > 2
    path = tmp_path / "damaged.mcap"

    def damaged(c):
        buf = bytearray(clean)
        buf[c.chunk_start_offset + 60] ^= 0x10  # inside its compressed data
        path.write_bytes(bytes(buf))
        return read_log(path)

    log = damaged(frames[len(frames) // 2])
    (d,) = log.damage
    lost = np.setdiff1d(clean_t, log.samples["t_host_ns"])
    assert len(lost) and d.after_ns <= lost.min() and lost.max() <= d.before_ns, \
        (d.after_ns - lost.min(), lost.max() - d.before_ns)
    assert "samples there are missing" in log.damage_note()
    log = damaged(view[len(view) // 2])
    assert len(log.damage) == 1 and np.array_equal(log.samples["t_host_ns"], clean_t)
    note = log.damage_note()
    assert "missing" not in note and "every sample is intact" in note, note
    # the last frames chunk: what it took leaves no gap in the numbering (no frame after it), and
    # the chunks after it (the view, the closing stats) hold no frames; its loss must still be said
    log = damaged(frames[-1])
    assert len(log.samples) < len(clean_t)
    assert "samples there are missing" in log.damage_note() and "intact" not in log.damage_note()


def _stid(*args):
    return subprocess.run([tool("stid"), *map(str, args)], capture_output=True, text=True, timeout=60)


def test_the_head_of_a_cut_file_is_called_cut_short_not_a_logger_without_a_car(small_log, tmp_path):
    """The first 3000 bytes of a log (a copy that stopped) hold no sample: that is a cut file,
    and the message said 'was the logger connected to the car?'."""
    from stid.errors import InputError
    from stid.load import load_mcap

    head = tmp_path / "head.mcap"
    head.write_bytes(small_log.read_bytes()[:3000])
    with pytest.raises(InputError, match="was cut short after 3000 bytes and holds 0 samples") as e:
        load_mcap(head)
    assert "connected" not in str(e.value)


def test_repair_keeps_every_metadata_record(small_log, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(small_log.read_bytes())
    out = tmp_path / "fixed.mcap"
    r = _stid("repair", cut, "-o", out)
    assert r.returncode == 0, r.stderr
    before, after = read_log(small_log), read_log(out)
    assert set(before.metadata) == set(after.metadata) >= {"stid.hello", "stid.stats", "stid.clock"}
    assert before.metadata == after.metadata
    assert np.array_equal(before.samples, after.samples)


def _copy_with_the_official_writer(src, dst, drop_last_frames: int = 0):
    """What another tool makes of a log: every message and metadata record copied by the
    official mcap Writer (its own chunks, channels mixed in each), optionally without the
    last ``drop_last_frames`` /stid/frames messages."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        reader = make_reader(f)
        msgs = list(reader.iter_messages(log_time_order=True))
        frames = [i for i, (_, ch, _) in enumerate(msgs) if ch.topic == "/stid/frames"]
        dropped = set(frames[len(frames) - drop_last_frames:]) if drop_last_frames else set()
        w = Writer(g, chunk_size=4096)
        w.start(profile=reader.get_header().profile, library="mcap python copy")
        seen_s, seen_c = {}, {}
        # in log-time order: per-sample messages and frames interleave in every chunk
        for i, (schema, channel, message) in enumerate(msgs):
            if i in dropped:
                continue
            if schema is not None and schema.id not in seen_s:
                seen_s[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in seen_c:
                seen_c[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                        seen_s.get(channel.schema_id, 0), channel.metadata)
            w.add_message(seen_c[channel.id], message.log_time, message.data, message.publish_time,
                          message.sequence)
        for rec in reader.iter_metadata():
            w.add_metadata(rec.name, rec.metadata)
        w.finish()


def test_a_copy_by_another_mcap_writer_loses_no_samples(small_log, tmp_path):
    """The official mcap Writer copies the channels (with stid-log's tag that /stid/samples
    has chunks of its own) but mixes channels in its chunks: the reader must not trust the
    tag there (it once skipped every chunk that began with a per-sample message, unreported)."""
    from mcap.reader import make_reader

    copy = tmp_path / "copy.mcap"
    _copy_with_the_official_writer(small_log, copy)
    a, b = read_log(small_log), read_log(copy)
    assert any(c.metadata.get("stid.chunks") == "own" for c in make_reader(open(copy, "rb")).get_summary()
               .channels.values())  # the tag came along
    assert not b.damage and np.array_equal(a.samples, b.samples) and not b.missing_frames
    assert b.damage_note() is None


def test_frames_missing_at_the_end_of_a_copy_are_reported(small_log, tmp_path):
    """A copy without its last frame messages is a well-formed file with consecutive frame
    numbers: only stid-log's closing count (stid.stats) shows the loss. It is said, with the
    count, and the samples that are there load as they are."""
    copy = tmp_path / "short.mcap"
    _copy_with_the_official_writer(small_log, copy, drop_last_frames=3)
    a, b = read_log(small_log), read_log(copy)
    assert not b.damage and b.missing_frames == a.frames - b.frames > 0
    note = b.damage_note()
    assert f"the last {b.missing_frames} are missing" in note
    assert np.array_equal(b.samples, a.samples[:len(b.samples)]) and len(b.samples) < len(a.samples)


def test_repair_refuses_a_hello_for_a_log_that_has_one_and_leaves_nothing(small_log, tmp_path):
    out = tmp_path / "fixed.mcap"
    r = _stid("repair", small_log, "-o", out, "--hello-from", small_log)
    assert r.returncode == 2 and "has a HELLO of its own" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and not (tmp_path / "fixed.mcap.part").exists()


def test_repair_refuses_foreign_and_empty_input(tmp_path):
    from mcap.writer import Writer

    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="someone")
        w.finish()
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    for src in (foreign, empty):
        out = tmp_path / f"{src.stem}.out.mcap"
        r = _stid("repair", src, "-o", out)
        assert r.returncode != 0 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, \
            r.stderr
        assert not out.exists()


def test_export_of_a_damaged_file_says_what_was_skipped(small_log, tmp_path):
    buf = bytearray(small_log.read_bytes())
    k = buf.find(b"\x04\x00\x00\x00zstd", len(buf) // 8)
    buf[k + 60] ^= 0x01
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(buf))
    r = _stid("export", bad, "--csv", tmp_path / "out.csv")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "failed their checks and were skipped" in r.stderr


def test_a_log_from_a_newer_stid_log_says_so(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "future.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="stid", library="stid-log 9")
        ch = w.register_channel("/stid/frames", "stid.frames.v9", 0)
        w.add_message(ch, 1, b"\x00", 1)
        w.finish()
    with pytest.raises(LogReadError, match="needs a newer stid"):
        read_log(path)
