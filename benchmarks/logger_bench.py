"""Logger figures: decode+write throughput against the USB full-speed ceiling for the
actual frame size, CPU share at 1 kHz in real time, MCAP -> arrays load rate on a
real-time-shaped log recorded through the pty path, and `stid-sim --fast` speed and
memory."""

from __future__ import annotations

import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import tty
import zlib
from pathlib import Path

import numpy as np
from cobs import cobs

from host import protocol as p
from host.mcap_log import McapLog, RAW_TOPIC
from host.mcap_read import read_log, scan_log
from host.recorder import Recorder

# USB 2.0 full speed, bulk transfers (a CDC-ACM serial port): at most 19 packets of 64
# bytes per 1 ms frame (USB 2.0 spec, table 5-9) = 1,216,000 bytes/s of payload, the
# best case with nothing else on the bus. 12 Mbit/s is the signalling rate, not payload.
USB_FS_BULK_BYTES_PER_S = 19 * 64 * 1000


def usb_fs_frames_per_s(bytes_per_frame: float) -> float:
    """Frames/s a USB full-speed CDC port can carry at most, for frames of this size on the wire."""
    return USB_FS_BULK_BYTES_PER_S / bytes_per_frame


def _frame(ftype: int, seq: int, t_us: int, body: bytes) -> bytes:
    raw = struct.pack("<BBII", 2, ftype, seq % p.MOD, t_us % p.MOD) + body
    return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"


def _hello(rate_hz: int, batch: int) -> bytes:
    doc = json.dumps({"proto": 2, "boot_id": "bench", "adc": {"bits": 12, "vref": 3.3, "unit": "count"},
                      "rate_hz": rate_hz, "batch": batch, "mod": p.MOD,
                      "wheels": [{"pulses_per_rev": 1, "wheel": "rl"}]}, separators=(",", ":")).encode()
    return doc


def frames_stream(seconds: float, rate_hz: int = 1000, batch: int = 10) -> bytes:
    """Protocol 2 SAMPLES frames (26-byte records) with a HELLO every second, as the firmware sends."""
    rng = np.random.default_rng(0)
    n = int(seconds * rate_hz)
    period = 1_000_000 // rate_hz
    recs = np.zeros(n, p.SAMPLE_DTYPE)
    recs["t_us"] = (np.arange(n) * period) % p.MOD
    for k in ("ax", "ay", "yaw"):
        recs[k] = rng.integers(1500, 2500, n)
    recs["az"] = p.MISSING
    recs["vbat"] = p.MISSING
    recs["steer_us"] = 1500
    recs["steer_t_us"] = recs["t_us"]
    hello = _hello(rate_hz, batch)
    out, seq = [], 0
    for i0 in range(0, n, batch):
        if i0 % rate_hz < batch:
            out.append(_frame(p.HELLO, seq, i0 * period, hello))
            seq += 1
        k = min(batch, n - i0)
        out.append(_frame(p.SAMPLES, seq, (i0 + k) * period, struct.pack("<IB", i0 % p.MOD, k)
                          + recs[i0:i0 + k].tobytes()))
        seq += 1
    return b"".join(out)


def throughput(quick: bool) -> dict:
    """Frames/s through decode + MCAP write, one sample per frame (the worst case)."""
    n = 20_000 if quick else 200_000
    stream = frames_stream(n / 1000, batch=1)
    frames = stream.count(b"\x00")
    per_frame = len(stream) / frames
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
    fps = frames / dt
    ceiling = usb_fs_frames_per_s(per_frame)
    return {"frames_per_s": fps, "bytes_per_frame": per_frame, "lost": lost, "usb_fs_frames_per_s": ceiling,
            "ratio_to_usb_fs": fps / ceiling}


class _PtyFeeder(threading.Thread):
    """Plays a byte stream into a pseudo-terminal at the firmware's pace (real time)."""

    def __init__(self, stream: bytes, seconds: float):
        super().__init__(daemon=True)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.stream, self.seconds = stream, seconds
        self.stop = threading.Event()

    def run(self):
        t0 = time.monotonic()
        sent = 0
        while not self.stop.is_set() and sent < len(self.stream):
            due = int(len(self.stream) * min(1.0, (time.monotonic() - t0) / self.seconds))
            if due > sent:
                try:
                    sent += os.write(self.master, self.stream[sent:due])
                except OSError:
                    break
            time.sleep(0.005)

    def close(self):
        self.stop.set()
        self.join(timeout=2)
        os.close(self.master)
        os.close(self.slave)


def record_through_pty(path, seconds: float, rate_hz: int = 1000, batch: int = 10) -> dict:
    """stid-log (a real process) records a real-time stream from a pty; returns the read shape."""
    stream = frames_stream(seconds + 1, rate_hz, batch)
    feeder = _PtyFeeder(stream, seconds + 1)
    bindir = Path(sys.executable).parent
    lg = subprocess.Popen([str(bindir / "stid-log"), feeder.port, "-o", str(path), "--duration", str(seconds)],
                          stderr=subprocess.DEVNULL)
    feeder.start()
    lg.wait(timeout=seconds + 60)
    feeder.close()
    # the size of each port read, from /stid/raw (stid.raw.v2: u32 n, n u32 lengths, ...)
    sc = scan_log(path)
    raw_id = next(c for c, ch in sc.channels.items() if ch.topic == RAW_TOPIC)
    sizes = []
    for m in sc.messages:
        if m.channel_id == raw_id:
            n = int.from_bytes(m.data[:4], "little")
            sizes.extend(np.frombuffer(m.data, "<u4", n, 4).tolist())
    return {"read_bytes": statistics.median(sizes), "reads_per_s": len(sizes) / seconds, "stream": stream}


def load_rate(quick: bool) -> dict:
    """Load rate of a real-time-shaped log: first a run recorded through the pty path by
    stid-log; then a 10-minute 1 kHz run (600k samples) written by the same recorder with
    that run's read size and the firmware's timing (10 real minutes would not fit the bench)."""
    pty_s = 5 if quick else 20
    minutes = 1 if quick else 10
    with tempfile.TemporaryDirectory() as d:
        small = Path(d) / "pty.mcap"
        shape = record_through_pty(small, pty_s)
        t0 = time.perf_counter()
        n_pty = len(read_log(small).samples)
        pty_rate = n_pty / (time.perf_counter() - t0)
        stream = frames_stream(minutes * 60)
        path = Path(d) / "run.mcap"
        log = McapLog(path, fsync=False)
        rec = Recorder(log)
        ns = time.time_ns()
        step = max(1, int(shape["read_bytes"]))
        bytes_per_s = len(stream) / (minutes * 60)
        for i in range(0, len(stream), step):
            rec.feed(stream[i:i + step], ns + int((i + step) / bytes_per_s * 1e9) + 2_000_000)
            log.maybe_flush()
        rec.finish(ns + minutes * 60 * 10**9)
        log.close()
        t0, c0 = time.perf_counter(), time.process_time()
        data = read_log(path)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        size = path.stat().st_size
    # CPU time too: on a shared machine the wall time also counts the other programs' turns
    return {"samples": len(data.samples), "seconds": dt, "samples_per_s": len(data.samples) / dt,
            "samples_per_cpu_s": len(data.samples) / cpu,
            "file_mb": size / 1e6, "read_bytes": shape["read_bytes"], "reads_per_s": shape["reads_per_s"],
            "pty_samples": n_pty, "pty_samples_per_s": pty_rate}


def _tree(pid: int) -> list[int]:
    """A process and all its descendants, now (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
        except (OSError, ValueError):
            pass  # it ended meanwhile
    return out


def _status_kb(pid: int) -> dict:
    """VmRSS and VmHWM [kB] of a process ({} once it has ended)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return {k: int(v.split()[0]) for k, v in (line.split(":", 1) for line in f) if k in ("VmRSS", "VmHWM")}
    except (OSError, ValueError):
        return {}


# Starts the command as its own child and prints that child's pid, then its rusage. A child's
# ru_maxrss counts its parent's peak too: exec keeps the high-water mark of the memory it
# replaces, which under vfork is the parent's (Linux exec_mmap, setmax_mm_hiwater_rss). Spawned
# straight from this harness, whose peak after the load benchmark is ~260 MB, stid-sim "peaked"
# at 261 MB; spawned from this small process, the figure is stid-sim's and its children's own.
_LAUNCHER = """
import os, sys
pid = os.spawnv(os.P_NOWAIT, sys.argv[1], sys.argv[1:])
print(pid, flush=True)
_, status, ru = os.wait4(pid, 0)
print(os.waitstatus_to_exitcode(status), ru.ru_maxrss, ru.ru_utime + ru.ru_stime, flush=True)
"""


def fast_sim(quick: bool) -> dict:
    """`stid-sim --fast` for a 10-minute run: wall time against real time, and memory.

    ``together_mb``: the most stid-sim and its MicroPython child held at one instant (their
    VmRSS summed, sampled every 20 ms; the simulation runs first, then the firmware beside the
    recording). ``max_mb``: the larger of the two peaks (``wait4``'s ru_maxrss, exact).
    ``peaks_mb``: each process's own peak (VmHWM), and ``sum_of_peaks_mb`` their sum, an upper
    bound that adds peaks which need not coincide."""
    seconds = 30 if quick else 600
    bindir = Path(sys.executable).parent
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        launcher = subprocess.Popen([sys.executable, "-c", _LAUNCHER, str(bindir / "stid-sim"), "--fast",
                                     "--duration", str(seconds), "-o", os.path.join(d, "run.mcap")],
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        pid = int(launcher.stdout.readline())
        peaks, together = {}, [0]
        done = threading.Event()

        def sample():
            while not done.is_set():
                now = 0
                for p in _tree(pid):
                    st = _status_kb(p)
                    if "VmRSS" in st:
                        now += st["VmRSS"]
                        name = "stid-sim" if p == pid else "micropython"
                        peaks[(name, p)] = max(peaks.get((name, p), 0), st["VmHWM"])
                together[0] = max(together[0], now)
                done.wait(0.02)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        code, maxrss_kb, cpu = launcher.stdout.readline().split()
        wall = time.perf_counter() - t0
        done.set()
        sampler.join()
        launcher.wait()
        s = read_log(os.path.join(d, "run.mcap")).samples
        run_s = (int(s["t_mcu_us"][-1]) - int(s["t_mcu_us"][0])) / 1e6  # the manoeuvre plus still and run-up
    by_name = {}
    for (name, _), kb in peaks.items():
        by_name[name] = max(by_name.get(name, 0), kb / 1024)
    # CPU too: on a shared machine the wall time also counts the other programs' turns
    cpu = float(cpu)
    return {"seconds": run_s, "wall_s": wall, "x_real_time": run_s / wall, "cpu_s": cpu,
            "x_real_time_cpu": run_s / cpu, "max_mb": int(maxrss_kb) / 1024, "together_mb": together[0] / 1024,
            "peaks_mb": by_name, "sum_of_peaks_mb": sum(by_name.values()), "ok": int(code) == 0}


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
