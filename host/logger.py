"""stid-log: record a serial port into an MCAP file, surviving whatever the link does.

- Everything read is archived raw; frames are decoded, unwrapped and written.
- The file is flushed and fsynced every second: a SIGKILL or power cut loses at
  most ~1 s. SIGINT/SIGTERM finish the file cleanly.
- An unplugged port is reopened by the same path (a /dev/serial/by-id link stays
  valid across replug); the gap is recorded and logging continues in the same file.
- Errors a user can cause end in one message and a non-zero exit.
"""

from __future__ import annotations

import errno
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import serial

from host.errors import HostError
from host.mcap_log import McapLog
from host.recorder import Recorder

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_NO_DATA = 3
EXIT_DISK = 4


class PortError(HostError):
    pass


class DiskError(HostError):
    exit_code = EXIT_DISK


class NoDataError(HostError):
    exit_code = EXIT_NO_DATA


@dataclass
class LogOptions:
    port: str
    output: str | None = None
    duration: float | None = None
    baud: int = 115200
    idle_timeout: float = 10.0  # s without any valid frame at the start -> give up
    reconnect_timeout: float | None = None  # s to wait for a replugged port (None: forever)
    flush_period: float = 1.0
    status: bool | None = None  # live status line (default: only on a terminal)


def default_output_name() -> str:
    return time.strftime("stid-%Y%m%d-%H%M%S.mcap")


def open_port(path: str, baud: int, read_timeout: float = 0.02) -> serial.Serial:
    try:
        return serial.Serial(path, baudrate=baud, timeout=read_timeout)
    except serial.SerialException as e:
        err = e.errno if isinstance(e.errno, int) else getattr(e.__context__, "errno", None)
        if err == errno.ENOENT or not os.path.exists(path):
            raise PortError(f"serial port {path} does not exist; plug the car in, or list ports with "
                            "'python -m serial.tools.list_ports'") from None
        if err in (errno.EACCES, errno.EPERM):
            raise PortError(f"no permission to open {path}: add your user to the 'dialout' group "
                            "(sudo usermod -aG dialout $USER) and log in again") from None
        if err == errno.EBUSY:
            raise PortError(f"{path} is busy: another program (a serial monitor?) has it open") from None
        raise PortError(f"cannot open {path}: {e}") from None


def _check_output(path: Path) -> None:
    try:
        parent = path.absolute().parent
        exists = parent.exists()
    except OSError as e:
        raise HostError(f"cannot reach the output directory of {path}: {e.strerror}") from None
    if not exists:
        raise HostError(f"output directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise HostError(f"cannot write to {parent}: choose another -o path")
    if path.is_dir():
        raise HostError(f"{path} is a directory: give a file name with -o")


class StatusLine:
    """One line on the terminal, rewritten in place; silent when not a terminal."""

    def __init__(self, enabled: bool, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self._last = 0.0
        self._width = 0

    def update(self, text: str, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < 0.25:
            return
        self._last = now
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self._width:
            self.stream.write("\n")
            self.stream.flush()


class Logger:
    def __init__(self, opts: LogOptions):
        self.opts = opts
        self.stop_reason: str | None = None
        self.port: serial.Serial | None = None
        self.path = Path(opts.output or default_output_name())

    def _on_signal(self, signum, frame):
        self.stop_reason = signal.Signals(signum).name

    def run(self) -> dict:
        o = self.opts
        _check_output(self.path)
        self.port = open_port(o.port, o.baud)  # before the file: a wrong port leaves no empty file
        try:
            log = McapLog(self.path)
        except OSError as e:
            raise DiskError(f"cannot create {self.path}: {e.strerror}") from None
        rec = Recorder(log)
        status = StatusLine(sys.stderr.isatty() if o.status is None else o.status)
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            return self._loop(log, rec, status)
        except NoDataError:
            self._close_after_error(log, rec)
            raise
        except OSError as e:
            if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise DiskError(f"disk full while writing {self.path}: it holds everything up to the last "
                                "flush (about a second ago); free some space, then run "
                                f"'stid repair {self.path}' to make it a complete file") from None
            raise DiskError(f"writing {self.path} failed: {e.strerror or e}") from None
        finally:
            for s, h in old.items():
                signal.signal(s, h)
            status.close()
            if self.port is not None:
                self.port.close()

    def _loop(self, log: McapLog, rec: Recorder, status: StatusLine) -> dict:
        o = self.opts
        t0 = self.t0 = time.monotonic()
        rec.event("connect", time.time_ns(), o.port)
        last_stats = t0
        rate_n, rate_t, rate = 0, t0, 0.0
        while self.stop_reason is None:
            now = time.monotonic()
            if o.duration is not None and now - t0 >= o.duration:
                self.stop_reason = "duration"
                break
            try:
                data = self.port.read(65536)
            except (serial.SerialException, OSError) as e:
                if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
                    raise
                if not self._reconnect(rec, log, status, str(e)):
                    break
                continue
            host_ns = time.time_ns()
            before = rec.samples
            rec.feed(data, host_ns)
            rate_n += rec.samples - before
            if rec.stats.accepted == 0 and now - t0 > o.idle_timeout:
                self._no_data(rec)
            log.maybe_flush(o.flush_period)
            if now - last_stats >= 1.0:
                rec.write_stats(host_ns)
                last_stats = now
            if now - rate_t >= 1.0:
                rate, rate_n, rate_t = rate_n / (now - rate_t), 0, now
            st = rec.stats
            status.update(f"{self.path.name}  {rate:6.0f} samples/s  frames {st.accepted}  lost {st.lost_frames}"
                          f"  crc {st.errors['crc']}  ay {rec.latest['ay']:+6.2f} m/s²"
                          f"  r {rec.latest['r']:+6.3f} rad/s")
        stats = rec.finish(time.time_ns())
        log.close()
        stats["stop"] = self.stop_reason
        stats["file"] = str(self.path)
        return stats

    def _close_after_error(self, log: McapLog, rec: Recorder) -> None:
        """Leave a complete file behind (or none, if the port never sent a byte)."""
        try:
            rec.finish(time.time_ns())
            log.close()
        except OSError:
            return
        if rec.stats.bytes == 0:
            self.path.unlink(missing_ok=True)

    def _no_data(self, rec: Recorder) -> None:
        if rec.stats.bytes == 0:
            msg = (f"no data from {self.opts.port} in {self.opts.idle_timeout:.0f} s: is the car powered and "
                   "the stid firmware running? ('stid flash' installs it)")
        else:
            msg = (f"{self.opts.port} sent {rec.stats.bytes} bytes but no valid stid frame in "
                   f"{self.opts.idle_timeout:.0f} s: wrong baud rate (--baud), or not the stid firmware? "
                   f"The bytes are kept in {self.path} (topic /stid/raw)")
        raise NoDataError(msg)

    def _reconnect(self, rec: Recorder, log: McapLog, status: StatusLine, why: str) -> bool:
        """The port went away: keep the file, wait for the same path to come back."""
        o = self.opts
        lost_ns = time.time_ns()
        rec.event("disconnect", lost_ns, why)
        rec.decoder.reset_link()
        log.flush()
        try:
            self.port.close()
        except (serial.SerialException, OSError):
            pass
        self.port = None
        t_lost = time.monotonic()
        while self.stop_reason is None:
            waited = time.monotonic() - t_lost
            if o.duration is not None and time.monotonic() - self.t0 >= o.duration:
                self.stop_reason = "duration"
                return False
            if o.reconnect_timeout is not None and waited > o.reconnect_timeout:
                self.stop_reason = "port gone"
                print(f"\n{o.port} did not come back within {o.reconnect_timeout:.0f} s; "
                      f"the file is complete up to the unplug", file=sys.stderr)
                return False
            status.update(f"{self.path.name}  port unplugged for {waited:4.1f} s, waiting for {o.port} ...")
            try:
                self.port = open_port(o.port, o.baud)
            except PortError:
                time.sleep(0.2)
                continue
            back_ns = time.time_ns()
            gap = {"from_ns": lost_ns, "to_ns": back_ns, "seconds": (back_ns - lost_ns) / 1e9}
            rec.gaps.append(gap)
            rec.event("reconnect", back_ns, f"{o.port} back after {gap['seconds']:.2f} s")
            log.flush()
            return True
        return False


def summary_line(stats: dict) -> str:
    e = stats["errors"]
    bad = sum(e.values())
    return (f"{stats['file']}: {stats['samples']} samples, {sum(stats['frames'].values())} frames, "
            f"{stats['lost_frames']} lost, {bad} rejected ({e['crc']} CRC), "
            f"{stats['missing_samples']} samples missing ({stats['mcu_overruns']} overrun on the car), "
            f"{len(stats['gaps'])} unplug gaps "
            f"[{stats['stop']}]")
