"""Faster than real time: run the firmware on the simulated board and record its
byte stream straight into an MCAP file (through the same recorder stid-log uses),
plus a CSV in the import contract and the truth beside them."""

from __future__ import annotations

import csv
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from cobs import cobs

from hil_sim.firmware_runner import run_firmware, start_firmware
from hil_sim.vehicle import board_opts
from hil_sim.run import SimConfig, SimRun, simulate_run, write_stimulus, write_truth
from host import protocol as p
from host import units
from host.frame_decoder import FrameDecoder
from host.mcap_log import McapLog
from host.recorder import Recorder

HOST_LATENCY_NS = 2_000_000  # a plausible USB + OS delay for the synthetic receive times


def firmware_bytes(run: SimRun) -> bytes:
    with tempfile.TemporaryDirectory(prefix="stid-sim-") as tmp:
        stim = Path(tmp) / "stimulus.bin"
        run.stimulus.write(stim)
        c = run.cfg
        return run_firmware(stim, rate_hz=c.rate_hz, batch=c.batch, ring_size=c.ring_size,
                            board_opts=board_opts(c.car))


FAULT_BLOCK = 1 << 16  # faults are drawn per block of this many clean bytes: the same seed, the same faults


def record(cfg: SimConfig, mcap_path, csv_path=None, truth_path=None, start_ns: int | None = None,
           faults=None) -> dict:
    """Simulate, run the firmware, record. ``faults`` (hil_sim.faults.LinkFaults) corrupt the
    bytes on their way to the recorder, as a lossy link does in real time (the CSV stays
    the clean stream's: it is the ideal logger's).

    The firmware's bytes are recorded as they come out of MicroPython (streamed, on the
    other core), not collected first: recording overlaps the firmware's run and the
    stream is never held whole (except for the CSV, which needs it). Nor is the simulation:
    the stimulus is written block by block (``write_stimulus``), unless the CSV needs the
    truth itself (``beta_sensor``)."""
    keep = bytearray() if csv_path else None
    active = faults is not None and faults.active
    with tempfile.TemporaryDirectory(prefix="stid-sim-") as tmp:
        stim = Path(tmp) / "stimulus.bin"
        if csv_path and cfg.beta_sensor is not None:
            run = simulate_run(cfg)
            run.stimulus.write(stim)
        else:
            run = SimRun(cfg, traj=None, stimulus=write_stimulus(cfg, stim), manoeuvre=None)
        if truth_path:
            write_truth(run, truth_path)
        c = run.cfg
        proc = start_firmware(stim, rate_hz=c.rate_hz, batch=c.batch, ring_size=c.ring_size,
                              board_opts=board_opts(c.car))
        err = bytearray()
        drain = threading.Thread(target=lambda: err.extend(proc.stderr.read()), daemon=True)
        drain.start()  # the board's stderr must not fill its pipe while we read stdout
        rs = RecordStream(mcap_path, start_ns)
        block = bytearray()
        fd = proc.stdout.fileno()
        while True:
            data = os.read(fd, 1 << 16)
            if keep is not None:
                keep += data
            if not active:
                if data:
                    rs.feed(data)
            else:
                block += data
                while len(block) >= FAULT_BLOCK or (not data and block):
                    rs.feed(faults.apply(bytes(block[:FAULT_BLOCK])))
                    del block[:FAULT_BLOCK]
            if not data:
                break
        proc.wait()
        drain.join()
        stats = rs.finish()
    if proc.returncode != 0:
        Path(mcap_path).unlink(missing_ok=True)  # what it holds is not a run
        raise RuntimeError("firmware failed on the simulated board:\n" + err.decode(errors="replace"))
    if csv_path:
        write_csv(run, bytes(keep), csv_path)
    return stats


FLUSH_US = 1_000_000  # as stid-log (host.logger) flushes, in the car's time


class RecordStream:
    """The firmware's bytes, in pieces of any size, through the recorder stid-log uses; each
    frame is received when the MCU sent it (its header time, unwrapped) plus a fixed latency."""

    def __init__(self, mcap_path, start_ns: int | None = None):
        self.start_ns = start_ns if start_ns is not None else time.time_ns()
        self.log = McapLog(mcap_path, fsync=False)
        self.rec = Recorder(self.log)
        self._tail = b""  # bytes after the last delimiter
        self._raw_t: int | None = None  # the last frame's MCU time as sent
        self._t = 0  # ... unwrapped
        self.base: int | None = None
        self._flushed_t: int | None = None  # MCU time [us] of the last flush

    def feed(self, data: bytes) -> None:
        buf = self._tail + data
        end = buf.rfind(b"\x00")
        if end < 0:
            self._tail = buf
            return
        self._tail = buf[end + 1:]
        pos = 0
        for part in buf[:end].split(b"\x00"):
            t = self._frame_time(part)
            if self.base is None:
                self.base = self.start_ns - t * 1000
                self.rec.event("connect", self.base, "simulated car, faster than real time")
            self.rec.feed(buf[pos:pos + len(part) + 1], self.base + t * 1000 + HOST_LATENCY_NS)
            pos += len(part) + 1
            # stid-log flushes every second: the file is shaped as a recording is (chunks of about
            # a second, so damage to one costs about a second of the run, not all of it)
            if self._flushed_t is None:
                self._flushed_t = t
            elif t - self._flushed_t >= FLUSH_US:
                self.log.flush()
                self._flushed_t = t

    def _frame_time(self, part: bytes) -> int:
        try:
            raw = cobs.decode(part)
            if len(raw) >= p.HEADER_SIZE:
                t = int.from_bytes(raw[6:10], "little")
                if self._raw_t is not None:
                    step = (t - self._raw_t) % p.MOD
                    self._t += step - p.MOD if step > p.MOD // 2 else step
                else:
                    self._t = t
                self._raw_t = t
        except cobs.DecodeError:
            pass  # a damaged frame is received with the last good one's time
        return self._t

    def finish(self) -> dict:
        if self._tail:
            t = self._t
            self.rec.feed(self._tail, (self.base or self.start_ns) + t * 1000 + HOST_LATENCY_NS)
        base = self.base if self.base is not None else self.start_ns
        stats = self.rec.finish(base + self._t * 1000 + HOST_LATENCY_NS)
        self.log.close()
        return stats


def record_stream(stream: bytes, mcap_path, start_ns: int | None = None) -> dict:
    """The firmware's bytes through the same recorder stid-log uses, with receive times
    that follow the MCU clock (plus a fixed latency), frame by frame."""
    rs = RecordStream(mcap_path, start_ns)
    rs.feed(stream)
    return rs.finish()


def write_csv(run: SimRun, stream: bytes, path) -> None:
    """The CSV an ideal logger writes (import contract, SI units), converted with the
    simulated car's own sensor constants: every column comes from the firmware's bytes
    (wheel speeds from the hall edges it timed), except ``beta`` (an extra sensor the
    car does not have, sampled from the truth at the sample instants)."""
    frames = FrameDecoder().feed(stream)
    s = p.samples_from_records((f.version, f.type, f.samples_bytes()) for f in frames if f.type in p.SAMPLE_TYPES)
    hello = next((f.hello() for f in frames if f.type == p.HELLO), {})
    car, sens = run.cfg.car, run.cfg.sens
    t_raw = s["t_us"].astype(np.int64)
    steps = np.diff(t_raw) % p.MOD
    t_mcu_us = t_raw[0] + np.concatenate([[0], np.cumsum(steps)])
    t = (t_mcu_us - t_raw[0]) * 1e-6
    if run.cfg.board == "pico":
        volts = lambda c: c.astype(float) / 4095 * sens.vs  # noqa: E731
    else:
        volts = lambda c: c.astype(float) / 1000.0  # noqa: E731
    g = 9.81
    ay = (volts(s["ay"]) / sens.vs - 0.5) * 10 * g
    ax = (volts(s["ax"]) / sens.vs - 0.5) * 10 * g
    r = np.radians((volts(s["yaw"]) - sens.gyro_zero) / sens.gyro_sens)
    steer = np.where(s["steer_us"] > 0, (s["steer_us"] - car.steer_center_us) / car.steer_us_per_rad, 0.0)
    # the logger's edge-period speed, each interval's mean at its middle (as stid export writes it)
    vx = units.wheel_speed(t_mcu_us, s["t_us"], s["wheel_count"], s["wheel_t_us"], run.cfg.wheel_ppr,
                           car.wheel_radius, centred=True)
    cols = {"t": t, "steer": steer, "ay": ay, "r": r, "vx": vx, "ax": ax, "delta_cmd": steer}
    if run.cfg.beta_sensor is not None:
        # an optical slip sensor (Correvit-style) sampled with the firmware's samples
        tr = run.traj
        beta = np.arctan2(tr.vy, np.maximum(tr.vx, 0.1))
        t_true = (t_raw - t_raw[0] + (t_raw[0] - run.cfg.start_ticks) % p.MOD) * 1e-6
        rng = np.random.default_rng(run.cfg.seed + 99)
        cols["beta"] = np.interp(t_true, tr.t, beta) + run.cfg.beta_sensor * rng.standard_normal(len(t))
    if run.cfg.wheel_speeds:
        # the four halls the firmware saw, by the host's edge-period method (host.units)
        w = units.wheel_speeds(t_mcu_us, s, hello, centred=True)
        for name in ("w_fl", "w_fr", "w_rl", "w_rr"):
            cols[name] = w[name]
        cols["vx"] = 0.5 * (w["w_fl"] + w["w_fr"]) * car.wheel_radius  # free-rolling fronts measure the speed
    write_columns(path, cols)


def write_columns(path, cols: dict) -> None:
    names = list(cols)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for row in zip(*(cols[n] for n in names)):
            if any(x != x for x in row):  # a value the samples cannot tell (NaN): the row is left out
                continue
            w.writerow([f"{row[0]:.6f}"] + [f"{x:.6g}" for x in row[1:]])


