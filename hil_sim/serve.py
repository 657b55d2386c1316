"""Serve the simulated car on a pseudo-terminal, in real time.

The firmware runs under MicroPython, paced to the wall clock; its bytes pass
through the link faults and are written to the pty master. The slave side is a
serial port like /dev/ttyUSB0 to whoever opens it. Writes never block: a full
pty buffer drops bytes (as a USB-CDC port with no reader does), so an absent
logger cannot stall the car.
"""

from __future__ import annotations

import errno
import os
import select
import signal
import sys
import termios
import tempfile
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hil_sim.faults import LinkFaults
from hil_sim.firmware_runner import start_firmware
from hil_sim.run import SimConfig, simulate_run, write_truth
from hil_sim.vehicle import board_opts


@dataclass
class ServeOptions:
    disconnect_at: float | None = None  # s after streaming starts
    reconnect_after: float = 2.0  # s unplugged
    link: str | None = None  # a stable symlink to the current pty (like /dev/serial/by-id)
    fault_log: str | None = None  # tests: clean stream + touched offsets (npz)
    truth: str | None = None
    faults: LinkFaults = field(default_factory=LinkFaults)


class Pty:
    def __init__(self, link: str | None):
        self.link = link
        self.open()

    def open(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave, termios.TCSANOW)  # no LF->CRLF, no 0x03 -> SIGINT
        os.set_blocking(self.master, False)
        self.name = os.ttyname(self.slave)
        if self.link:
            tmp = self.link + ".tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.name, tmp)
            os.replace(tmp, self.link)

    def write(self, data: bytes) -> int:
        """Write what fits; return the number of bytes dropped."""
        try:
            n = os.write(self.master, data)
        except BlockingIOError:
            n = 0
        except OSError as e:
            if e.errno in (errno.EIO, errno.EAGAIN):
                n = 0
            else:
                raise
        return len(data) - n

    def drain_input(self):
        # whatever the logger sends (it sends nothing) is read and ignored
        try:
            while select.select([self.master], [], [], 0)[0]:
                if not os.read(self.master, 4096):
                    break
        except OSError:
            pass

    def close(self):
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        # unplugged, the link goes, as udev removes /dev/serial/by-id/...: left behind, it names
        # a pty number the system gives the next program that asks, and a logger waiting for
        # the car would open that program's port
        try:
            if self.link and os.readlink(self.link) == self.name:
                os.unlink(self.link)
        except OSError:
            pass


def serve(cfg: SimConfig, opts: ServeOptions, out=None) -> int:
    out = out or sys.stdout
    pty = Pty(opts.link)
    print(f"port: {pty.name}", file=out, flush=True)
    if opts.link:
        print(f"link: {opts.link}", file=out, flush=True)
    stop = {"flag": False}

    def on_signal(signum, frame):
        stop["flag"] = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    run = simulate_run(cfg)
    if opts.truth:
        write_truth(run, opts.truth)
    tmp = tempfile.TemporaryDirectory(prefix="stid-sim-")
    stim = Path(tmp.name) / "stimulus.bin"
    run.stimulus.write(stim)
    proc = start_firmware(stim, rate_hz=cfg.rate_hz, batch=cfg.batch, ring_size=cfg.ring_size, realtime=True,
                          board_opts=board_opts(cfg.car))
    clean = bytearray()
    dropped = 0
    t_start = time.monotonic()
    unplugged_until = None
    try:
        fd = proc.stdout.fileno()
        while not stop["flag"]:
            r, _, _ = select.select([fd], [], [], 0.05)
            now = time.monotonic() - t_start
            if opts.disconnect_at is not None and unplugged_until is None and now >= opts.disconnect_at:
                pty.close()
                unplugged_until = now + opts.reconnect_after
                print(f"unplugged at {now:.2f} s", file=out, flush=True)
            if unplugged_until is not None and unplugged_until > 0 and now >= unplugged_until:
                pty.open()
                unplugged_until = -1.0  # once
                print(f"port: {pty.name}", file=out, flush=True)
            if not r:
                if proc.poll() is not None:
                    break
                continue
            data = os.read(fd, 65536)
            if not data:
                break
            off = len(clean)
            clean += data
            sent = opts.faults.apply(bytes(data))
            if unplugged_until is not None and unplugged_until > 0:
                opts.faults.touched.extend(range(off, off + len(data)))  # nobody is listening
                continue
            lost = pty.write(sent)
            if lost:
                dropped += lost
                opts.faults.touched.extend(range(off, off + len(data)))
            pty.drain_input()
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=5)
        for s, h in old.items():
            signal.signal(s, h)
        time.sleep(0.3)  # let the reader take the last bytes before the port goes away
        pty.close()
        if opts.link and os.path.islink(opts.link):
            os.unlink(opts.link)
        tmp.cleanup()
        if opts.fault_log:
            np.savez(opts.fault_log, clean=np.frombuffer(bytes(clean), dtype=np.uint8),
                     touched=np.unique(np.asarray(opts.faults.touched, dtype=np.int64)))
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode not in (0, None, -signal.SIGTERM) and not stop["flag"]:
        print(f"stid-sim: error: the firmware stopped on the simulated board:\n{err}", file=sys.stderr)
        return 1
    return 0
