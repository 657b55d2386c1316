"""stid-log owns its port and says loudly when nothing useful is recorded.

A feeder thread plays a hand-framed stream (test_files_damage.circle_stream: plain
physics, written in the test) into a pseudo-terminal at about real time; stid-log
runs as a real process on the other side.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
import tty

import numpy as np
import pytest

from conftest import tool
from host.mcap_read import read_log
from test_files_damage import circle_stream


class Feeder:
    """A pty that plays ``stream`` at ``rate`` bytes/s; ``link`` follows it like a by-id link."""

    def __init__(self, stream: bytes, rate: float = 16_000, link=None, loop: bool = True):
        self.link = link
        self.stop = threading.Event()
        self.pause = threading.Event()
        self._open()
        self.stream, self.rate, self.loop = stream, rate, loop
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)
        if self.link:
            tmp = str(self.link) + ".tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.port, tmp)
            os.replace(tmp, self.link)

    def _run(self):
        pos, step = 0, int(self.rate * 0.02)
        while not self.stop.is_set():
            time.sleep(0.02)
            if self.pause.is_set():
                continue
            if pos >= len(self.stream):
                if not self.loop:
                    continue
                pos = 0
            try:
                os.write(self.master, self.stream[pos:pos + step])
            except OSError:
                pass
            pos += step

    def unplug_and_replace(self, stream: bytes):
        """The device goes away; a moment later the link points at a new pty playing ``stream``."""
        self.pause.set()
        for fd in (self.master, self.slave):
            os.close(fd)
        if self.link:
            os.unlink(self.link)  # as udev removes a by-id link on unplug
        time.sleep(0.5)
        self._open()
        self.stream = stream
        self.pause.clear()

    def close(self):
        self.stop.set()
        self.thread.join(timeout=2)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def logger(port, out, *args):
    return subprocess.Popen([tool("stid-log"), str(port), "-o", str(out), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def one_line_error(err: str) -> str:
    lines = [x for x in err.strip().splitlines() if x.startswith("stid-log: error")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def feeder():
    made = []

    def make(*a, **k):
        f = Feeder(*a, **k)
        made.append(f)
        return f

    yield make
    for f in made:
        f.close()


def test_a_second_logger_on_the_same_port_fails_at_once(tmp_path, feeder):
    f = feeder(circle_stream(8.0), loop=False)
    first = logger(f.port, tmp_path / "a.mcap", "--duration", 6)
    time.sleep(1.0)
    t0 = time.monotonic()
    # asked for 20 s, it must end at once: within its start-up (up to ~4 s of imports on a loaded
    # 2-core machine), not after its duration, nor after the first logger's 6 s
    second = subprocess.run([tool("stid-log"), f.port, "-o", str(tmp_path / "b.mcap"), "--duration", "20"],
                            capture_output=True, text=True, timeout=30)
    assert time.monotonic() - t0 < 8.0
    assert first.poll() is None, "the second logger failed only once the first had finished"
    assert second.returncode == 2
    line = one_line_error(second.stderr)
    # it names the program to stop: the first logger, by its pid
    assert "already in use" in line and f"stid-log {f.port}" in line and f"(pid {first.pid})" in line, line
    assert not (tmp_path / "b.mcap").exists()
    _, err = first.communicate(timeout=30)
    assert first.returncode == 0, err
    s = read_log(tmp_path / "a.mcap").samples
    assert len(s) > 0.8 * 3 * 500 and (s["index"][1:] - s["index"][:-1] == 1).all()  # nothing stolen


def test_sighup_finishes_the_file_like_sigterm(tmp_path, feeder):
    f = feeder(circle_stream(4.0))
    lg = logger(f.port, tmp_path / "run.mcap", "--duration", 30)
    time.sleep(2.0)
    lg.send_signal(signal.SIGHUP)
    _, err = lg.communicate(timeout=15)
    assert lg.returncode == 0, err
    log = read_log(tmp_path / "run.mcap")
    assert not log.truncated and "stid.stats" in log.metadata and len(log.samples) > 300


def test_a_run_without_hello_exits_non_zero_and_a_later_supply_makes_it_usable(tmp_path, feeder):
    good = feeder(circle_stream(3.0), loop=False)
    lg = logger(good.port, tmp_path / "earlier.mcap", "--duration", 2.5)
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    bare = feeder(circle_stream(8.0, hello_every_s=None))
    lg = logger(bare.port, tmp_path / "bare.mcap", "--duration", 6.5)
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 5
    assert "without a HELLO" in one_line_error(err) and "--hello-from" in err
    assert "no HELLO got through" in err  # the live warning came first
    events = [e[1]["event"] for e in read_log(tmp_path / "bare.mcap").events]
    assert "no_hello" in events
    fixed = tmp_path / "fixed.mcap"
    r = subprocess.run([tool("stid"), "repair", str(tmp_path / "bare.mcap"), "-o", str(fixed), "--hello-from",
                        str(tmp_path / "earlier.mcap")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "warning" in r.stderr and "cannot tell whether it is the same board" in r.stderr
    log = read_log(fixed)
    assert log.hello["supplied_from"] == str(tmp_path / "earlier.mcap")
    assert log.hello["uid"] == read_log(tmp_path / "earlier.mcap").hello["uid"]
    # with no earlier log: the HELLO declared in the vehicle file's [board] table, written here
    # from what the board sent; the run converts to the same SI samples
    from stid.load import load_runs
    from stid.vehicle_file import load_vehicle

    sent = read_log(tmp_path / "earlier.mcap").hello
    car = tmp_path / "car.toml"
    car.write_text('name = "circle car"\nmass = 9.31\na = 0.2326\nb = 0.2874\n\n'
                   '[steering]\ncenter_us = 1500.0\nus_per_rad = 1145.9\n\n'
                   '[wheel]\nradius = 0.045\npulses_per_rev = 1\n\n'
                   f'[board]\nproto = {sent["proto"]}\nrate_hz = {sent["rate_hz"]}\nmod = {sent["mod"]}\n'
                   f'adc = {{bits = {sent["adc"]["bits"]}, vref = {sent["adc"]["vref"]}, unit = "count"}}\n'
                   'wheels = [{pulses_per_rev = 1, wheel = "rl"}]\n')
    from_car = tmp_path / "from_car.mcap"
    r = subprocess.run([tool("stid"), "repair", str(tmp_path / "bare.mcap"), "-o", str(from_car), "--hello-from",
                        str(car)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "[board] table" in r.stderr and "nothing can check it" in r.stderr
    assert read_log(from_car).hello["supplied_from"] == f"{car} [board]"
    vehicle = load_vehicle(car)
    (a,), (b,) = load_runs([fixed], vehicle), load_runs([from_car], vehicle)
    for name in ("steer", "ay", "r", "vx"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_frames_of_a_newer_protocol_say_update_stid(tmp_path, feeder):
    f = feeder(circle_stream(3.0, version=9))
    r = subprocess.run([tool("stid-log"), f.port, "-o", str(tmp_path / "x.mcap"), "--idle-timeout", "1.5"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 3
    line = one_line_error(r.stderr)
    assert "newer stid" in line and "baud" not in line


def test_a_lossy_link_warns_live_and_records_the_event(tmp_path, feeder):
    import numpy as np

    clean = circle_stream(6.0)
    frames = clean.split(b"\x00")
    rng = np.random.default_rng(3)
    bad = bytearray()
    for fr in frames[:-1]:
        fr = bytearray(fr)
        if fr and rng.random() < 0.3:  # 30% of frames damaged in transit
            k = int(rng.integers(0, len(fr)))
            fr[k] = (fr[k] ^ 0x5A) or 1
        bad += fr + b"\x00"
    f = feeder(bytes(bad))
    lg = logger(f.port, tmp_path / "run.mcap", "--duration", 4)
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    assert "rejected in the last second" in err and "CRC" in err
    events = [e[1] for e in read_log(tmp_path / "run.mcap").events]
    assert any(e["event"] == "rejects" for e in events)


def test_a_quiet_port_is_not_an_unplug(tmp_path, feeder):
    f = feeder(circle_stream(10.0))
    lg = logger(f.port, tmp_path / "run.mcap", "--duration", 8)
    time.sleep(2.0)
    f.pause.set()
    time.sleep(4.0)
    f.pause.clear()
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    assert "no valid frame for" in err
    log = read_log(tmp_path / "run.mcap")
    assert log.stats["gaps"] == []
    assert "silence" in [e[1]["event"] for e in log.events]
    assert "disconnect" not in [e[1]["event"] for e in log.events]


def test_another_board_after_a_replug_is_refused(tmp_path, feeder):
    link = tmp_path / "by-id-car"
    f = feeder(circle_stream(10.0, uid="aaaa000000000001"), link=link)
    lg = logger(link, tmp_path / "run.mcap", "--duration", 12, "--reconnect-timeout", 5)
    time.sleep(2.5)
    f.unplug_and_replace(circle_stream(10.0, uid="bbbb000000000002"))
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 6
    line = one_line_error(err)
    assert "another board" in line and "bbbb000000000002" in line
    log = read_log(tmp_path / "run.mcap")
    assert not log.truncated
    assert {h[1]["uid"] for h in log.hellos} == {"aaaa000000000001"}  # nothing of the other board written


def test_the_same_board_after_a_replug_continues_in_the_file(tmp_path, feeder):
    link = tmp_path / "by-id-car"
    stream = circle_stream(10.0, uid="aaaa000000000001")
    f = feeder(stream, link=link)
    lg = logger(link, tmp_path / "run.mcap", "--duration", 7, "--reconnect-timeout", 5)
    time.sleep(2.5)
    f.unplug_and_replace(stream)
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    log = read_log(tmp_path / "run.mcap")
    ev = [e[1] for e in log.events]
    rec = [e for e in ev if e["event"] == "reconnect"]
    assert len(rec) == 1 and "same board: uid aaaa000000000001" in rec[0]["detail"]
    assert len(log.stats["gaps"]) == 1


def test_a_run_without_hello_takes_one_from_an_earlier_log_when_told(tmp_path, feeder):
    good = feeder(circle_stream(3.0), loop=False)
    lg = logger(good.port, tmp_path / "earlier.mcap", "--duration", 2.5)
    assert lg.wait(timeout=30) == 0
    bare = feeder(circle_stream(5.0, hello_every_s=None))
    lg = logger(bare.port, tmp_path / "bare.mcap", "--duration", 3, "--hello-from", tmp_path / "earlier.mcap")
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    assert "warning: no HELLO was received" in err
    from stid.load import load_file

    runs = load_file(tmp_path / "bare.mcap")
    assert any("supplied from" in w for r in runs for w in r.meta.get("warnings", []))


def test_another_usb_serial_number_after_a_replug_is_refused(monkeypatch, tmp_path):
    """Where the OS gives a USB serial number (an RP2040's is its flash id), a replugged
    port with another number is another board, refused before a byte of it is read."""
    from host import logger as lg_mod
    from host.recorder import Recorder

    monkeypatch.setattr(lg_mod, "port_identity", lambda path: {"path": path, "usb_serial": "E6614C311B2A"})
    lg = lg_mod.Logger(lg_mod.LogOptions(port="/dev/ttyACM0", output=str(tmp_path / "x.mcap")))
    lg.identity = {"usb_serial": "E66038B7132F"}
    with pytest.raises(lg_mod.OtherBoardError, match="E6614C311B2A"):
        lg._identify(Recorder.__new__(Recorder))


@pytest.mark.parametrize("baud", ["-1", "0", "99999999999", "fast"])
def test_a_baud_rate_no_uart_has_is_refused_in_one_line(tmp_path, baud):
    """A fresh user's `--baud -1` ended in pyserial's ValueError traceback, 99999999999 in an
    OverflowError, and 0 (hang up, on a real line) was taken."""
    r = subprocess.run([tool("stid-log"), str(tmp_path / "ttyUSB9"), "--baud", baud, "-o", str(tmp_path / "x.mcap")],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    said = [line for line in r.stderr.splitlines() if "error" in line]  # (after argparse's usage)
    assert len(said) == 1 and "--baud" in said[0] and "bits per second" in said[0], r.stderr
    assert not (tmp_path / "x.mcap").exists()
