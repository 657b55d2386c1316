"""Logger figures: decode+write throughput against USB line rate, CPU share at
1 kHz in real time, and MCAP -> arrays load rate."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
from cobs import cobs

from host import protocol as p
from host.mcap_log import McapLog
from host.mcap_read import read_log
from host.recorder import Recorder

USB_FS_FRAMES_PER_S = 40_000  # ~12 Mbit/s full speed, ~30-byte frames, after protocol overhead


def _frames(n_frames: int, per_frame: int, rate_hz: int = 1000) -> list[bytes]:
    rng = np.random.default_rng(0)
    out = []
    idx = 0
    for seq in range(n_frames):
        recs = bytearray()
        for k in range(per_frame):
            t = ((idx + k) * (1_000_000 // rate_hz)) % p.MOD
            recs += struct.pack("<IHHHHHHIH", t, *rng.integers(1500, 2500, 4), 1500, 0, 0, 0xFFFF)
        body = struct.pack("<IB", idx % p.MOD, per_frame) + bytes(recs)
        idx += per_frame
        raw = struct.pack("<BBII", 1, p.SAMPLES, seq % p.MOD, int(idx * 1e6 / rate_hz) % p.MOD) + body
        out.append(cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00")
    return out


def _hello() -> bytes:
    import json

    doc = json.dumps({"proto": 1, "boot_id": "bench", "adc": {"bits": 12, "vref": 3.3, "unit": "count"},
                      "rate_hz": 1000, "batch": 1, "mod": p.MOD}).encode()
    raw = struct.pack("<BBII", 1, p.HELLO, 0, 0) + doc
    return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"


def throughput(quick: bool) -> dict:
    """Frames/s through decode + MCAP write, one sample per frame (the worst case)."""
    n = 20_000 if quick else 200_000
    stream = _hello() + b"".join(_frames(n, 1))
    with tempfile.TemporaryDirectory() as d:
        log = McapLog(Path(d) / "t.mcap", fsync=True)
        rec = Recorder(log)
        t0 = time.perf_counter()
        ns = time.time_ns()
        for i in range(0, len(stream), 4096):  # the port delivers ~4 KiB at a time at line rate
            rec.feed(stream[i:i + 4096], ns + i * 1000)
            log.maybe_flush()
        rec.finish(ns)
        log.close()
        dt = time.perf_counter() - t0
        lost = rec.stats.lost_frames + rec.stats.rejected
    fps = n / dt
    return {"frames_per_s": fps, "bytes_per_frame": len(stream) / n, "lost": lost,
            "ratio_to_usb_fs": fps / USB_FS_FRAMES_PER_S}


def load_rate(quick: bool) -> dict:
    """Load a 10-minute 1 kHz run (600k samples, 10 per frame) from MCAP into arrays."""
    minutes = 1 if quick else 10
    n_frames = minutes * 60 * 100
    stream = _hello() + b"".join(_frames(n_frames, 10))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "run.mcap"
        log = McapLog(path, fsync=False)
        rec = Recorder(log)
        ns = time.time_ns()
        for i in range(0, len(stream), 4096):
            rec.feed(stream[i:i + 4096], ns + i * 100)
        rec.finish(ns)
        log.close()
        t0 = time.perf_counter()
        data = read_log(path)
        dt = time.perf_counter() - t0
        size = path.stat().st_size
    return {"samples": len(data.samples), "seconds": dt, "samples_per_s": len(data.samples) / dt,
            "file_mb": size / 1e6}


def cpu_at_1khz(quick: bool) -> dict:
    """CPU share of stid-log recording the simulated car at 1 kHz in real time."""
    seconds = 4 if quick else 20
    bindir = Path(sys.executable).parent
    with tempfile.TemporaryDirectory() as d:
        sim = subprocess.Popen([str(bindir / "stid-sim"), "--duration", str(seconds), "--still", "0.5",
                                "--rate", "1000", "--batch", "10"], stdout=subprocess.PIPE, text=True)
        port = sim.stdout.readline().split(": ", 1)[1].strip()
        t0 = time.perf_counter()
        lg = subprocess.Popen([str(bindir / "stid-log"), port, "-o", os.path.join(d, "r.mcap"),
                               "--duration", str(seconds + 6), "--reconnect-timeout", "0.5"],
                              stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(lg.pid, 0)
        wall = time.perf_counter() - t0
        sim.wait()
        samples = len(read_log(os.path.join(d, "r.mcap")).samples)
    cpu = usage.ru_utime + usage.ru_stime
    return {"cpu_s": cpu, "wall_s": wall, "cpu_share": cpu / wall, "samples": samples}
