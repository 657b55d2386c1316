"""stid-log: record a serial port into an MCAP file, surviving whatever the link does.

- Everything read is archived raw; frames are decoded, unwrapped and written.
- The file is flushed and fsynced every second: a SIGKILL or power cut loses at
  most ~1 s. SIGINT/SIGTERM finish the file cleanly.
- The port is opened exclusively: a second logger on it fails at once.
- An unplugged port is reopened by the same path (a /dev/serial/by-id link stays
  valid across replug). What comes back must be the same board: its USB serial
  number (where the port has one) and the ``uid`` of its next HELLO are checked
  before a byte of it is written; another board ends the run with a clear message.
  Only then is the gap recorded and logging continues in the same file. A quiet
  port is not an unplug: it is warned about (``host.link_watch``), not a gap.
- SIGINT, SIGTERM and SIGHUP (terminal closed) finish the file cleanly.
- A run that ends without any HELLO exits non-zero (or takes one with
  ``--hello-from`` from an earlier log of the same board, and says so).
- Errors a user can cause end in one message and a non-zero exit.
"""

from __future__ import annotations

import errno
import re
import os
import signal
import stat
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import serial

from host import protocol as p
from host.errors import HostError
from host.frame_decoder import FrameDecoder
from host.link_watch import LinkWatch, advice, describe_rejects
from host.mcap_log import McapLog
from host.mcap_scan import holds_a_log
from host.recorder import Recorder

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_NO_DATA = 3
EXIT_DISK = 4
EXIT_NO_HELLO = 5
EXIT_OTHER_BOARD = 6
IDENTIFY_S = 3.0  # after a replug, wait this long for a HELLO (sent every 1-2 s) to tell the board


def _gone_in_words(why: str) -> str:
    """pyserial's words for a port that closed under it, as a person says them (the file's
    'disconnect' event keeps pyserial's own)."""
    if "returned no data" in why or "Errno 5]" in why or "Input/output error" in why:
        return "it closed: unplugged, or the car or simulator on it ended"
    return why


class PortError(HostError):
    pass


class DiskError(HostError):
    exit_code = EXIT_DISK


class NoDataError(HostError):
    exit_code = EXIT_NO_DATA


class NoHelloError(HostError):
    exit_code = EXIT_NO_HELLO


class OtherBoardError(HostError):
    exit_code = EXIT_OTHER_BOARD


@dataclass
class LogOptions:
    port: str
    output: str | None = None
    duration: float | None = None
    baud: int = p.LINK_BAUD  # what the firmware sets (ESP32 UART); USB-CDC ignores it
    idle_timeout: float = 10.0  # s without any valid frame at the start -> give up
    reconnect_timeout: float | None = None  # s to wait for a replugged port (None: forever)
    flush_period: float = 1.0
    status: bool | None = None  # live status line (default: only on a terminal)
    hello_from: str | None = None  # an earlier log of the same board, if no HELLO arrives
    overwrite: bool = False  # replace an existing -o file (never by default: it may be a run)
    live: list | None = None  # arguments of the live view (stid live FILE --follow ...); None: no view


def default_output_name() -> str:
    return time.strftime("stid-%Y%m%d-%H%M%S.mcap")


TAIL_BYTES = 2048
TEXT_SHARE = 0.9  # of bytes printable ASCII: text, not a binary stream at the wrong baud rate


def text_sent(tail: bytes, lines: int = 3, width: int = 120) -> str:
    """The last lines of ``tail`` quoted, when it is text (a MicroPython traceback, a prompt), else ''."""
    if len(tail) < 16:
        return ""
    printable = sum(32 <= b < 127 or b in (9, 10, 13) for b in tail)
    if printable < TEXT_SHARE * len(tail):
        return ""
    got = [ln.strip() for ln in tail.decode("ascii", "replace").splitlines() if ln.strip()]
    # the error a traceback ends in first (a REPL's banner and prompt follow it), then the last lines
    errors = [ln for ln in got if re.match(r"[A-Za-z_.]*(Error|Exception)\b", ln)]
    shown = ([errors[-1]] if errors else []) + [ln for ln in got[-lines:] if not errors or ln != errors[-1]]
    return " | ".join(repr(ln[:width]) for ln in shown[:lines])


def restart_causes(reset_cause: str | None) -> str:
    """What restarts a car, for the warning: its watchdog fires when its sampler stops (an
    exception in it), not when the host stops reading (firmware/README.md: the watchdog is fed by
    the sampler's progress, never by the host)."""
    if reset_cause == "watchdog":
        return "the watchdog restarts the car when its sampler stops (an exception in it), not when the host stops reading"
    return "a brown-out (a sagging battery under the motor's current), the reset button or a crash restarts it"


def open_port(path: str, baud: int, read_timeout: float = 0.02) -> serial.Serial:
    try:
        # exclusive: a second program opening the port would steal half the bytes of each
        return serial.Serial(path, baudrate=baud, timeout=read_timeout, exclusive=True)
    except serial.SerialException as e:
        err = e.errno if isinstance(e.errno, int) else getattr(e.__context__, "errno", None)
        if err in (errno.EAGAIN, errno.EWOULDBLOCK):
            holders = port_holders(path)
            who = (", ".join(f"{name} (pid {pid})" for pid, name in holders) if holders
                   else "another program (another stid-log?)")
            raise PortError(f"{path} is already in use by {who}; stop it first, one logger per port") from None
        if err == errno.ENOENT or not os.path.exists(path):
            raise PortError(f"serial port {path} does not exist; plug the car in, or list ports with "
                            "'python -m serial.tools.list_ports'") from None
        if err in (errno.EACCES, errno.EPERM):
            raise PortError(f"no permission to open {path}: add your user to the 'dialout' group "
                            "(sudo usermod -aG dialout $USER) and log in again") from None
        if err == errno.EBUSY:
            raise PortError(f"{path} is busy: another program (a serial monitor?) has it open") from None
        if err == errno.ENOTTY or (os.path.exists(path) and not stat.S_ISCHR(os.stat(path).st_mode)):
            raise PortError(f"{path} is not a serial port (it is a {'directory' if os.path.isdir(path) else 'file'}): "
                            "give the car's port, e.g. /dev/ttyACM0 or /dev/ttyUSB0; to read a recorded "
                            "file use stid, e.g. 'stid fit FILE'") from None
        raise PortError(f"cannot open {path}: {e}") from None


def port_holders(path: str) -> list[tuple[int, str]]:
    """The processes that have ``path``'s device open (Linux: /proc/PID/fd), as (pid, command
    line), so that "in use" names which program to stop. Empty where /proc says nothing."""
    try:
        real = os.path.realpath(path)
        pids = [d for d in os.listdir("/proc") if d.isdigit() and int(d) != os.getpid()]
    except OSError:
        return []
    found = []
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
            if not any(os.readlink(f"/proc/{pid}/fd/{fd}") == real for fd in fds):
                continue
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
        except OSError:  # gone meanwhile, or another user's
            continue
        # the program and its first arguments: "stid-log /dev/ttyACM0 -o run.mcap", not a full path
        words = [os.path.basename(argv[0])] + argv[1:4] if argv else ["?"]
        if len(words) > 1 and words[0].startswith("python") and argv[1:]:
            words = [os.path.basename(argv[1])] + argv[2:5]
        found.append((int(pid), " ".join(words)))
    return found


def port_identity(path: str) -> dict:
    """What the OS says about the device behind ``path``: its USB serial number (on an
    RP2040 the flash's unique id; the same board whatever its boot), vid, pid. Empty
    values for a port that has none (a pty, a plain UART)."""
    from serial.tools import list_ports

    real = os.path.realpath(path)
    for info in list_ports.comports():
        if os.path.realpath(info.device) == real:
            return {"path": path, "device": info.device, "usb_serial": info.serial_number or "",
                    "vid": info.vid or 0, "pid": info.pid or 0, "description": info.description or ""}
    return {"path": path, "device": real, "usb_serial": "", "vid": 0, "pid": 0, "description": ""}


def _check_output(path: Path, overwrite: bool = False) -> None:
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
    if path.is_file() and not overwrite:  # (a device, /dev/null, is not a file to keep)
        what = "a recorded run" if holds_a_log(path) else "a file"
        raise HostError(f"{path} exists ({what}): give another -o path, or --overwrite to replace it")


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
        self.path = Path(opts.output) if opts.output else None  # None: a new name when the run starts
        self._tail = bytearray()  # the last bytes the port sent, while no frame has come (text_sent says them)

    def _create_log(self) -> McapLog:
        """The output, created here and now: -o as given (replaced only with --overwrite), or a
        name from the clock, made unique (-2, -3, ...) when a file of that name exists, another
        logger's of the same second included (the create is exclusive, so the two cannot race)."""
        named = self.path is not None
        base = self.path or Path(default_output_name())
        for k in range(1, 1000):
            path = base if k == 1 else base.with_name(f"{base.stem}-{k}{base.suffix}")
            try:
                # (a device given as -o, /dev/null, exists and is opened as it is)
                device = path.exists() and not path.is_file()
                log = McapLog(path, exclusive=not (named and (self.opts.overwrite or device)))
            except FileExistsError:
                if named:
                    raise HostError(f"{path} appeared while the port was opened: give another -o path") from None
                continue
            except OSError as e:
                raise DiskError(f"cannot create {path}: {e.strerror}") from None
            self.path = path
            return log
        raise DiskError(f"cannot find a free name like {base} in {base.absolute().parent}")

    def _on_signal(self, signum, frame):
        self.stop_reason = signal.Signals(signum).name

    def run(self) -> dict:
        o = self.opts
        # (a name from the clock that exists is made unique when the file is created)
        _check_output(self.path or Path(default_output_name()), overwrite=o.overwrite or self.path is None)
        self.port = open_port(o.port, o.baud)  # before the file: a wrong port leaves no empty file
        log = self._create_log()
        rec = Recorder(log)
        self.identity = port_identity(o.port)
        log.metadata("stid.port", self.identity)
        self.live = None
        if o.live is not None:
            from host.live_view import LiveView

            self.live = LiveView(self.path, o.live)
        # (with a live view the terminal is the view's: its table has the rates in it)
        status = StatusLine(False if self.live else sys.stderr.isatty() if o.status is None else o.status)
        self.status = status
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        try:
            stats = self._loop(log, rec, status)
        except (NoDataError, OtherBoardError):
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
            if self.live is not None:
                self.live.finish()  # (the file is closed: the view's last update is on all of it)
        if not rec.hello_seen and rec.samples and rec.supplied_hello is None:
            errs = describe_rejects({k: v for k, v in rec.stats.errors.items() if v})
            raise NoHelloError(
                f"the run ended without a HELLO from the board ({stats['samples']} samples in {self.path}; "
                f"rejected frames: {errs or 'none'}), so their ADC scale is unknown: run "
                f"'stid repair {self.path} --hello-from EARLIER.mcap' with a log of the same board, or --hello-from "
                f"V.toml with a vehicle file whose [board] table declares it (docs/hello_in_vehicle_file.md), or log again")
        return stats

    def _warn(self, rec: Recorder, event: str, text: str) -> None:
        """A warning a person must see now, and an event in the file."""
        rec.event(event, time.time_ns(), text)
        self._say(f"warning: {text}")

    def _say(self, text: str) -> None:
        """A line for the person logging, terminal or not (the status line makes way for it;
        a live view shows it above its table)."""
        if self.live is not None and self.live.say(f"stid-log: {text}"):
            return
        self.status.close()
        self.status._width = 0
        print(f"stid-log: {text}", file=sys.stderr, flush=True)

    def _loop(self, log: McapLog, rec: Recorder, status: StatusLine) -> dict:
        o = self.opts
        t0 = self.t0 = time.monotonic()
        rec.event("connect", time.time_ns(), f"{o.port} (USB serial {self.identity['usb_serial'] or 'none'})")
        watch = LinkWatch(t0)
        boots_seen = 1
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
            if data and not rec.stats.accepted:
                self._tail = (self._tail + data)[-TAIL_BYTES:]
            if len(rec.uids) > 1:
                raise OtherBoardError(
                    f"another board (uid {rec.uids[-1]}, was {rec.uids[0]}) is sending on {o.port}; {self.path} "
                    "ends here (its last frames, after the 'boot' event, are the other board's); "
                    "start a new log for it")
            rate_n += rec.samples - before
            if len(rec.boots) > boots_seen:  # the car restarted: say so now, not only in the summary
                boots_seen = len(rec.boots)
                r = rec.car_restarts()[-1]
                self._warn(rec, "restart", f"the car restarted (reset cause: {r['reset_cause'] or 'not yet known'}"
                           + (f", {r['gap_s']:.1f} s without samples" if r["gap_s"] is not None else "")
                           + "): the run goes on as a new piece; " + restart_causes(r["reset_cause"]))
            if rec.stats.accepted == 0 and now - t0 > o.idle_timeout:
                self._no_data(rec)
            log.maybe_flush(o.flush_period)
            if now - last_stats >= 1.0:
                rec.write_stats(host_ns)
                last_stats = now
                for event, text in watch.check(now, rec.stats, rec.samples, rec.hello_seen, True):
                    self._warn(rec, event, text)
                if self.live is not None and not self.live.alive:  # (it said why itself, above)
                    code, self.live = self.live.proc.returncode, None
                    self._warn(rec, "live_view", f"the live view ended (exit {code}); recording goes on, and "
                               f"'stid live {self.path} --vehicle V.toml --follow' in another shell shows it again")
            if now - rate_t >= 1.0:
                rate, rate_n, rate_t = rate_n / (now - rate_t), 0, now
            st = rec.stats
            status.update(f"{self.path.name}  {rate:6.0f} samples/s  frames {st.accepted}  lost {st.lost_frames}"
                          f"  crc {st.errors['crc']}  ay {rec.latest['ay']:+6.2f} m/s²"
                          f"  r {rec.latest['r']:+6.3f} rad/s")
        if not rec.hello_seen and rec.samples and o.hello_from:
            from host.hello_supply import hello_from_file

            doc, warning = hello_from_file(o.hello_from, self.identity)
            rec.supply_hello(doc, str(o.hello_from))
            self._warn(rec, "hello", warning)
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
        elif rec.stats.rejected and rec.stats.errors.get("version_newer", 0) >= 0.5 * rec.stats.rejected:
            msg = (f"{self.opts.port} sends frames of a newer stid protocol ({rec.stats.errors['version_newer']} "
                   f"rejected): this log needs a newer stid (pip install -U stid). The bytes are kept in "
                   f"{self.path} (topic /stid/raw)")
        else:
            why = describe_rejects(rec.stats.errors)
            text = text_sent(bytes(self._tail))
            if text:  # a board at its REPL (the firmware raised, or was never started) prints text
                hint = (f"it sends text, not frames; its last lines: {text} (a board at its MicroPython prompt "
                        "sends text: the firmware stopped with an error, or is not installed ('stid flash'); else "
                        "another device is on this port)")
            else:
                hint = advice(rec.stats.errors) if why else "wrong baud rate (--baud), or not the stid firmware?"
            msg = (f"{self.opts.port} sent {rec.stats.bytes} bytes but no valid stid frame in "
                   f"{self.opts.idle_timeout:.0f} s (rejected: {why or 'nothing frame-like'}): "
                   f"{hint.rstrip('.?')}{'?' if hint.endswith('?') else '.'} "
                   f"The bytes are kept in {self.path} (topic /stid/raw)")
        raise NoDataError(msg)

    def _reconnect(self, rec: Recorder, log: McapLog, status: StatusLine, why: str) -> bool:
        """The port went away: keep the file, wait for the same path to come back, and
        accept it only as the same board."""
        o = self.opts
        lost_ns = time.time_ns()
        rec.event("disconnect", lost_ns, why)
        rec.decoder.reset_link()
        log.flush()
        self._close_port()
        t_lost = time.monotonic()
        wait = (f"at most {o.reconnect_timeout:g} s" if o.reconnect_timeout is not None
                else "until it comes back (--reconnect-timeout to limit; Ctrl-C ends the log)")
        # (the file has its 'disconnect' event already: this is for the person only)
        self._say(f"warning: {o.port} went away ({_gone_in_words(why)}); {self.path} is complete up to here; "
                  f"waiting {wait} for the same board")
        while self.stop_reason is None:
            waited = time.monotonic() - t_lost
            if o.duration is not None and time.monotonic() - self.t0 >= o.duration:
                self.stop_reason = "duration"
                return False
            if o.reconnect_timeout is not None and waited > o.reconnect_timeout:
                self.stop_reason = "port gone"
                # (through _say: a live view shows it above its table instead of drawing over it)
                self._say(f"{o.port} did not come back within {o.reconnect_timeout:.0f} s; "
                          f"the file is complete up to the unplug")
                return False
            status.update(f"{self.path.name}  port unplugged for {waited:4.1f} s, waiting for {o.port} ...")
            try:
                self.port = open_port(o.port, o.baud)
            except PortError:
                time.sleep(0.2)
                continue
            held = self._identify(rec)
            if held is None:  # gone again, or stopped, while identifying
                continue
            back_ns = held[0][1] if held else time.time_ns()
            gap = {"from_s": lost_ns / 1e9, "to_s": back_ns / 1e9, "seconds": (back_ns - lost_ns) / 1e9}
            rec.gaps.append(gap)
            rec.event("reconnect", back_ns, f"{o.port} back after {gap['seconds']:.2f} s ({self._same_how})")
            self._say(f"{o.port} is back after {gap['seconds']:.1f} s ({self._same_how}); logging goes on in "
                      f"{self.path}")
            for data, ns in held:
                rec.feed(data, ns)
            log.flush()
            return True
        return False

    def _close_port(self) -> None:
        try:
            self.port.close()
        except (serial.SerialException, OSError):
            pass
        self.port = None

    def _identify(self, rec: Recorder):
        """Read from the reopened port without writing until it is known to be the same
        board. Returns the (bytes, host_ns) read meanwhile, or None if the port went away.
        Raises OtherBoardError for another board."""
        o = self.opts
        ident = port_identity(o.port)
        was, now_serial = self.identity.get("usb_serial"), ident.get("usb_serial")
        if was and now_serial and was != now_serial:
            raise OtherBoardError(
                f"after the unplug, {o.port} is another device (USB serial {now_serial}, was {was}); "
                f"{self.path} holds the first board's run up to the unplug; start a new log for the other one")
        uids = list(rec.uids)
        probe = FrameDecoder(track_seq=False)
        held: list = []
        t0 = time.monotonic()
        quiet_warned = False
        while self.stop_reason is None:
            if o.duration is not None and time.monotonic() - self.t0 >= o.duration:
                self.stop_reason = "duration"
                return None
            try:
                data = self.port.read(65536)
            except (serial.SerialException, OSError):
                self._close_port()
                return None
            if data:
                held.append((data, time.time_ns()))
                if not probe.stats.accepted and len(held) > 2000:
                    del held[:1000]  # not a stid board (so far): nothing of it will be written
                for fr in probe.feed(data):
                    if fr.type != p.HELLO:  # either form
                        continue
                    try:
                        uid = fr.hello().get("uid")
                    except (ValueError, UnicodeDecodeError):
                        continue
                    if uids and uid and uid not in uids:
                        raise OtherBoardError(
                            f"after the unplug, another board answers on {o.port} (uid {uid}, was {uids[-1]}); "
                            f"{self.path} holds the first board's run up to the unplug; start a new log for it")
                    self._same_how = (f"same board: uid {uid}" if uids and uid else
                                      f"same USB serial {was}" if was and now_serial else
                                      "same board not checked: no uid, no USB serial")
                    return held
            elapsed = time.monotonic() - t0
            if probe.stats.accepted and elapsed >= IDENTIFY_S:
                self._same_how = (f"same USB serial {was}" if was and now_serial else
                                  "same board not checked: no HELLO yet")
                return held
            if not probe.stats.accepted and elapsed >= o.idle_timeout and not quiet_warned:
                quiet_warned = True
                self._warn(rec, "silence", f"{o.port} is back but sends no stid frame in {elapsed:.0f} s: "
                                           "another device, or the car not running? Nothing is recorded from it")
                held.clear()
        return None


def summary_line(stats: dict) -> str:
    e = stats["errors"]
    bad = sum(e.values())
    restarts = stats.get("car_restarts", [])
    said = ""
    if restarts:
        what = ", ".join(f"{r['reset_cause'] or 'cause unknown'}"
                         + (f", {r['gap_s']:.1f} s without samples" if r["gap_s"] is not None else "")
                         for r in restarts)
        said = f", {len(restarts)} restart{'s' if len(restarts) > 1 else ''} of the car ({what})"
    return (f"{stats['file']}: {stats['samples']} samples, {sum(stats['frames'].values())} frames, "
            f"{stats['lost_frames']} lost, {bad} rejected ({e['crc']} CRC), "
            f"{stats['missing_samples']} samples missing ({stats['mcu_overruns']} overrun, {stats.get('mcu_missed', 0)} timer periods missed on the car), "
            f"{len(stats['gaps'])} unplug gaps{said}; {stop_words(stats['stop'])}")


def stop_words(reason) -> str:
    """Why the log ended, in words (the file's stats keep the short code)."""
    if reason == "duration":
        return "stopped after --duration"
    if reason == "port gone":
        return ("stopped: the port went away (unplugged, or the car or simulator on it closed it) and did not "
                "come back within --reconnect-timeout")
    if reason in ("SIGINT", "SIGTERM", "SIGHUP"):
        return {"SIGINT": "stopped by Ctrl-C", "SIGTERM": "stopped by SIGTERM (kill)",
                "SIGHUP": "stopped: its terminal closed (SIGHUP)"}[reason]
    return f"stopped ({reason})" if reason else "stopped"
