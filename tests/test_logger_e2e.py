"""stid-sim -> pseudo-terminal -> stid-log -> MCAP, as real processes, in real time."""

import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest
from cobs import cobs

from conftest import tool
from host.mcap_read import read_log
from host.mcap_log import FRAMES_TOPIC


class Sim:
    def __init__(self, *args):
        self.proc = subprocess.Popen([tool("stid-sim"), *map(str, args)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        first = self.proc.stdout.readline().strip()
        assert first.startswith("port: /dev/pts/"), first
        self.port = first.split(": ", 1)[1]

    def wait(self, timeout=60):
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err
        return out


def start_logger(port, out, *args):
    return subprocess.Popen([tool("stid-log"), port, "-o", str(out), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def clean_frames(fault_log):
    d = np.load(fault_log)
    clean = d["clean"].tobytes()
    touched = np.zeros(len(clean) + 1, bool)
    touched[d["touched"]] = True
    frames, spans = [], []
    pos = 0
    while True:
        end = clean.find(b"\x00", pos)
        if end < 0:
            break
        chunk = clean[pos:end]
        if chunk:
            frames.append(cobs.decode(chunk)[:-4])
            spans.append((max(pos - 1, 0), end))  # from the previous delimiter to our own
        pos = end + 1
    intact = [not touched[a:b + 1].any() for a, b in spans]
    return frames, intact


def logged_frames(path):
    from host.mcap_read import scan_log, split_frames

    sc = scan_log(path)
    topics = {cid: c.topic for cid, c in sc.channels.items()}
    out = []
    for m in sc.messages:
        if topics.get(m.channel_id) == FRAMES_TOPIC:
            out.extend(split_frames(m.data))
    return out


def test_faulty_link_every_intact_frame_recovered_no_corrupt_accepted(tmp_path):
    flog = tmp_path / "faults.npz"
    sim = Sim("--duration", 4, "--still", 0.5, "--seed", 11, "--ber", 2e-4, "--drop-rate", 2e-5,
              "--insert-rate", 2e-5, "--fault-log", flog)
    lg = start_logger(sim.port, tmp_path / "run.mcap", "--duration", 30, "--reconnect-timeout", 0.5)
    sim.wait()
    out, err = lg.communicate(timeout=60)
    assert lg.returncode == 0, err
    frames, intact = clean_frames(flog)
    got = logged_frames(tmp_path / "run.mcap")
    by_seq = {}
    for pl in got:
        seq = int.from_bytes(pl[2:6], "little")
        assert pl == frames[seq], f"corrupt frame accepted (seq {seq})"
        by_seq[seq] = pl
    # frames sent before the logger opened the port were flushed by the open (pyserial
    # clears the input queue), as on a real port: judge from the first frame logged on
    first = min(by_seq)
    missed = [i for i, ok in enumerate(intact) if ok and i >= first and i not in by_seq]
    assert not missed, f"{len(missed)} intact frames lost: {missed[:5]}"
    assert sum(intact) < len(frames), "no fault was injected: the test would prove nothing"
    log = read_log(tmp_path / "run.mcap")
    seqs = sorted(by_seq)
    assert log.stats["lost_frames"] == (seqs[-1] - seqs[0] + 1) - len(seqs)
    assert log.stats["errors"]["crc"] + log.stats["errors"]["cobs"] > 0
    assert np.all(np.diff(log.samples["index"]) >= 1)  # order kept, no duplicates
    assert "samples" in err and "lost" in err  # the one-line summary


def test_sigkill_loses_at_most_a_second_and_repair_completes(tmp_path):
    sim = Sim("--duration", 8, "--still", 0.5, "--seed", 4)
    out = tmp_path / "run.mcap"
    lg = start_logger(sim.port, out, "--duration", 60)
    time.sleep(5.0)
    kill_ns = time.time_ns()
    lg.send_signal(signal.SIGKILL)
    lg.wait(timeout=10)
    sim.proc.terminate()
    sim.proc.wait(timeout=10)
    log = read_log(out)
    assert log.truncated
    assert len(log.samples) > 500
    last = log.samples["t_host_ns"].max()
    assert (kill_ns - last) / 1e9 <= 1.3, f"lost {(kill_ns - last) / 1e9:.2f} s before the kill"
    fixed = tmp_path / "fixed.mcap"
    r = subprocess.run([tool("stid-log"), "--repair", str(out), "--repair-output", str(fixed)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    again = read_log(fixed)
    assert not again.truncated
    assert np.array_equal(again.samples, log.samples)
    from mcap.reader import make_reader

    with open(fixed, "rb") as f:
        assert make_reader(f).get_summary() is not None


def test_sigint_finishes_the_file_cleanly(tmp_path):
    sim = Sim("--duration", 5, "--still", 0.5, "--seed", 6)
    out = tmp_path / "run.mcap"
    lg = start_logger(sim.port, out, "--duration", 60)
    time.sleep(3.0)
    lg.send_signal(signal.SIGINT)
    _, err = lg.communicate(timeout=15)
    sim.proc.terminate()
    sim.proc.wait(timeout=10)
    assert lg.returncode == 0, err
    assert "Traceback" not in err
    log = read_log(out)
    assert not log.truncated and len(log.samples) > 300
    assert "stid.stats" in log.metadata
    # the samples' log times, in the order they were taken, never run back (a refit of the
    # clock moved them back by up to 10 ms)
    from mcap.reader import make_reader

    from host.mcap_log import SI_TOPIC

    with open(out, "rb") as f:
        times = [(json.loads(m.data)["index"], m.log_time)
                 for _, c, m in make_reader(f).iter_messages(topics=[SI_TOPIC], log_time_order=False)]
    t = np.array([lt for _, lt in sorted(times)], dtype=np.int64)
    assert len(t) > 300 and np.all(np.diff(t) >= 0), np.diff(t).min()


def test_unplug_and_replug_resumes_in_the_same_file(tmp_path):
    link = tmp_path / "by-id-car"
    sim = Sim("--duration", 7, "--still", 0.5, "--seed", 8, "--disconnect-at", 3.0, "--reconnect-after", 1.0,
              "--link", link)
    out = tmp_path / "run.mcap"
    time.sleep(0.2)
    lg = start_logger(str(link), out, "--duration", 60, "--reconnect-timeout", 2.0)
    sim.wait()
    _, err = lg.communicate(timeout=60)
    assert lg.returncode == 0, err
    log = read_log(out)
    events = [e[1]["event"] for e in log.events]
    assert "disconnect" in events and "reconnect" in events
    assert len(log.stats["gaps"]) == 1 and 0.5 < log.stats["gaps"][0]["seconds"] < 3.0
    s = log.samples
    assert np.all(np.diff(s["index"]) >= 1) and np.all(np.diff(s["t_mcu_us"]) > 0)  # no duplicates, no reorder
    jumps = np.flatnonzero(np.diff(s["index"]) > 1)
    assert len(jumps) >= 1  # the unplugged second is missing, and nothing else
    t_gap = (s["t_mcu_us"][jumps[0] + 1] - s["t_mcu_us"][jumps[0]]) / 1e6
    assert 0.5 < t_gap < 3.0
    # said live, also when stderr is not a terminal (it printed nothing while it waited)
    assert "went away" in err and "is complete up to here" in err and "is back after" in err, err
    # in words (pyserial's own, "device reports readiness to read but returned no data", stays in the file)
    assert "went away (it closed: unplugged" in err and "readiness" not in err, err
    assert any("readiness" in e[1].get("detail", "") or "Errno" in e[1].get("detail", "") for e in log.events
               if e[1]["event"] == "disconnect"), log.events


def test_an_unplugged_car_takes_its_link_away_as_udev_does(tmp_path):
    """A /dev/serial/by-id link goes when the device goes. The simulator left its link on the
    closed pty, whose number the system then gave another program's pty: in the suite a
    logger waiting for its car opened another test's port ("already in use" there)."""
    link = tmp_path / "by-id-car"
    sim = Sim("--duration", 4, "--still", 0.5, "--seed", 8, "--disconnect-at", 1.0, "--reconnect-after", 1.5,
              "--link", link)
    seen = []
    while sim.proc.poll() is None:
        seen.append(os.path.lexists(link))
        time.sleep(0.05)
    sim.wait()
    changes = [seen[0]] + [b for a, b in zip(seen, seen[1:]) if a != b]
    assert changes == [True, False, True, False], changes  # there; unplugged: gone; back; the end: gone


def test_a_car_restart_is_said_live_and_in_the_summary(tmp_path):
    """A car whose sampler stops is restarted by its 2 s watchdog: the summary said '0 samples
    missing ... 0 unplug gaps' with a 2 s hole in the run and nothing live."""
    sim = Sim("--duration", 5, "--still", 0.5, "--seed", 10, "--car-fault", "1.5")
    out = tmp_path / "run.mcap"
    lg = start_logger(sim.port, out, "--duration", 60)
    sim.wait()
    lg.send_signal(signal.SIGINT)
    _, err = lg.communicate(timeout=30)
    assert lg.returncode == 0, err
    assert "warning: the car restarted" in err, err
    # (it blamed "a stall of the host past the car's 2 s watchdog", which firmware/README.md rules out)
    assert "when its sampler stops" in err and "stall of the host" not in err, err
    summary = err.strip().splitlines()[-1]
    assert "1 restart of the car (watchdog, " in summary and "s without samples" in summary, summary
    log = read_log(out)
    (r,) = log.stats["car_restarts"]
    assert r["reset_cause"] == "watchdog" and 2.0 < r["gap_s"] < 4.0, r


# -- bad input ------------------------------------------------------------------

def run_logger(*args, timeout=30):
    return subprocess.run([tool("stid-log"), *map(str, args)], capture_output=True, text=True, timeout=timeout)


def assert_clean_failure(r, code, *words):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in r.stderr, r.stderr


def test_port_that_does_not_exist(tmp_path):
    r = run_logger("/dev/ttyUSB99", "-o", tmp_path / "x.mcap")
    assert_clean_failure(r, 2, "does not exist")
    assert not (tmp_path / "x.mcap").exists()
    # a recorded file given as the port ('Could not configure port: (25, Inappropriate ioctl ...)')
    (tmp_path / "run.mcap").write_bytes(b"\x89MCAP0\r\n")
    r = run_logger(tmp_path / "run.mcap", "-o", tmp_path / "y.mcap")
    assert_clean_failure(r, 2, "is not a serial port (it is a file)", "stid fit FILE")
    assert not (tmp_path / "y.mcap").exists()


NOBODY = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]


def _nobody_can_run_stid_log():
    if os.geteuid() != 0:
        return False
    r = subprocess.run(NOBODY + [tool("stid-log"), "--help"], capture_output=True, timeout=30)
    return r.returncode == 0


@pytest.mark.skipif(not _nobody_can_run_stid_log(), reason="needs root to run stid-log as an unprivileged user")
def test_port_without_permission(tmp_path):
    """An unprivileged user (not in dialout) opening a root-owned port."""
    import tempfile

    master, slave = os.openpty()
    name = os.ttyname(slave)
    os.chmod(name, 0o600)
    out_dir = tempfile.mkdtemp(prefix="stid-perm-", dir="/tmp")
    os.chmod(out_dir, 0o777)
    try:
        cmd = NOBODY + [tool("stid-log"), name,
               "-o", os.path.join(out_dir, "x.mcap")]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    finally:
        os.close(master)
        os.close(slave)
        os.rmdir(out_dir)
    assert_clean_failure(r, 2, "no permission", "dialout")


def test_device_that_sends_nothing(tmp_path):
    master, slave = os.openpty()
    try:
        r = run_logger(os.ttyname(slave), "-o", tmp_path / "x.mcap", "--idle-timeout", 1)
    finally:
        os.close(master)
        os.close(slave)
    assert_clean_failure(r, 3, "no data", "firmware")
    assert not (tmp_path / "x.mcap").exists()  # nothing received, no empty file left behind


def test_garbage_on_the_port(tmp_path):
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    rng = np.random.default_rng(1)
    garbage = rng.integers(1, 256, 20000, dtype=np.uint8).tobytes()  # a wrong baud rate looks like this
    proc = subprocess.Popen([tool("stid-log"), os.ttyname(slave), "-o", str(tmp_path / "x.mcap"),
                             "--idle-timeout", "1.5"], stderr=subprocess.PIPE, text=True)
    t_end = time.time() + 1.2
    while time.time() < t_end:
        os.write(master, garbage[:2000])
        time.sleep(0.05)
    _, err = proc.communicate(timeout=30)
    os.close(master)
    os.close(slave)
    r = subprocess.CompletedProcess(proc.args, proc.returncode, "", err)
    assert_clean_failure(r, 3, "no valid stid frame", "baud")
    log = read_log(tmp_path / "x.mcap")  # kept, complete, the bytes archived
    assert not log.truncated and log.stats["bytes"] > 10000


def test_a_board_at_its_prompt_is_quoted(tmp_path):
    """A board whose firmware raised at boot sits at the MicroPython prompt and sends its traceback:
    stid-log said only 'wrong baud rate, or not the stid firmware?', and the error that says why
    was in /stid/raw alone."""
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    text = (b"Traceback (most recent call last):\r\n  File \"main.py\", line 29, in <module>\r\n"
            b"ValueError: rate_hz must be 10..5000 and divide 1000000 (a whole number of us)\r\n"
            b"MicroPython v1.26.0 on 2025-08-09; Raspberry Pi Pico with RP2040\r\n"
            b"Type \"help()\" for more information.\r\n>>> ")
    proc = subprocess.Popen([tool("stid-log"), os.ttyname(slave), "-o", str(tmp_path / "x.mcap"),
                             "--idle-timeout", "3"], stderr=subprocess.PIPE, text=True)
    time.sleep(1.0)  # (once the logger has the port: what came before it opened is not its)
    os.write(master, text)
    _, err = proc.communicate(timeout=30)
    os.close(master)
    os.close(slave)
    r = subprocess.CompletedProcess(proc.args, proc.returncode, "", err)
    assert_clean_failure(r, 3, "no valid stid frame", "sends text", "'ValueError: rate_hz must be 10..5000")


def test_full_disk(tmp_path):
    master, slave = os.openpty()
    try:
        frame = cobs.encode(b"\x01\x03" + bytes(8) + bytes(28) + bytes(4)) + b"\x00"
        os.write(master, frame * 20)
        r = run_logger(os.ttyname(slave), "-o", "/dev/full", "--duration", 3)
    finally:
        os.close(master)
        os.close(slave)
    assert_clean_failure(r, 4, "disk full")


def test_file_size_limit_mid_run(tmp_path):
    """A disk that fills up while logging: the file holds everything up to the last flush."""
    sim = Sim("--duration", 6, "--still", 0.5, "--seed", 9)
    out = tmp_path / "run.mcap"
    lg = subprocess.Popen(["prlimit", "--fsize=60000", tool("stid-log"), sim.port, "-o", str(out),
                           "--duration", "30"], stderr=subprocess.PIPE, text=True)
    _, err = lg.communicate(timeout=60)
    sim.proc.terminate()
    sim.proc.wait(timeout=10)
    assert lg.returncode == 4, err
    assert "disk full" in err and "stid repair" in err and "Traceback" not in err
    log = read_log(out)
    assert log.truncated and len(log.samples) > 100


def test_status_line_on_a_terminal_and_quiet_when_piped(tmp_path):
    sim = Sim("--duration", 3, "--still", 0.5, "--seed", 2)
    term_master, term_slave = os.openpty()  # stid-log's stderr is a terminal here
    lg = subprocess.Popen([tool("stid-log"), sim.port, "-o", str(tmp_path / "a.mcap"), "--duration", "30",
                           "--reconnect-timeout", "0.5"], stderr=term_slave, stdout=subprocess.DEVNULL)
    os.close(term_slave)
    seen = b""
    while True:
        try:
            chunk = os.read(term_master, 4096)
        except OSError:
            break
        if not chunk:
            break
        seen += chunk
    lg.wait(timeout=30)
    sim.proc.wait(timeout=30)
    os.close(term_master)
    assert b"\r" in seen and b"samples/s" in seen and b"m/s" in seen
    sim2 = Sim("--duration", 2, "--still", 0.5, "--seed", 2)
    piped = subprocess.run([tool("stid-log"), sim2.port, "-o", str(tmp_path / "b.mcap"), "--duration", "30",
                            "--reconnect-timeout", "0.5"], capture_output=True, text=True, timeout=60)
    sim2.proc.wait(timeout=30)
    assert "\r" not in piped.stderr
    # the unplug's warning, the port-gone note and the summary: a line each, no status line
    assert len(piped.stderr.strip().splitlines()) <= 3, piped.stderr


def test_a_recorded_run_is_never_replaced(tmp_path, monkeypatch):
    """stid-log -o onto an existing run replaced it (598 kB -> 53 kB), export --csv onto a run
    wrote CSV text over it, repair -o replaced another run, and two loggers started in the
    same second shared one default name: one run lost each time, exit 0."""
    run, other = tmp_path / "keep.mcap", tmp_path / "other.mcap"
    for path, seed in ((run, 1), (other, 2)):
        subprocess.run([tool("stid-sim"), "--fast", "--duration", "1", "--seed", str(seed), "-o", str(path)],
                       check=True, capture_output=True, timeout=120)
    before = run.read_bytes()
    master, slave = os.openpty()
    try:
        r = run_logger(os.ttyname(slave), "-o", run, "--duration", 1)
        assert_clean_failure(r, 2, "exists (a recorded run)", "--overwrite")
        assert run.read_bytes() == before
        notes = tmp_path / "notes.txt"
        notes.write_text("mine")
        r = run_logger(os.ttyname(slave), "-o", notes, "--duration", 1)
        assert_clean_failure(r, 2, "exists (a file)")
        assert notes.read_text() == "mine"
    finally:
        os.close(master)
        os.close(slave)
    for cmd, says in ((["stid", "export", str(other), "--csv", str(run)], "export never replaces one"),
                      (["stid", "repair", str(other), "-o", str(run)], "repair never replaces one")):
        r = subprocess.run([tool(cmd[0]), *cmd[1:]], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, (cmd, r.stderr)
        assert run.read_bytes() == before
    # the default name from the clock, taken already: the new run gets its own
    from host import logger

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(logger, "default_output_name", lambda: "stid-20261123-030021.mcap")
    (tmp_path / "stid-20261123-030021.mcap").write_bytes(before)
    lg = logger.Logger(logger.LogOptions(port="unused"))
    log = lg._create_log()
    log.close()
    assert lg.path.name == "stid-20261123-030021-2.mcap"
    assert (tmp_path / "stid-20261123-030021.mcap").read_bytes() == before


def test_a_simulated_car_of_its_own_is_a_board_of_its_own(tmp_path):
    """Every simulated car had one machine.unique_id(): a trial's logger, waiting for its car to
    come back (the same board only), took the next stid-sim on that pty, another car, for its own
    and recorded 11,600 of its samples into the run. A --car file is now a board of its own (the
    same one on every run of it); the reference car keeps the uid it always had."""
    cars = {"reference": []}
    for name, text in (("a", "mass = 5.8\nIz = 0.13\n"), ("b", "mass = 6.1\n")):
        (tmp_path / f"{name}.toml").write_text(text)
        cars[name] = ["--car", str(tmp_path / f"{name}.toml")]
    uid = {}
    for name, args in [*cars.items(), ("a again", cars["a"])]:
        out = tmp_path / f"{name}.mcap"
        subprocess.run([tool("stid-sim"), "--fast", "--duration", "1", "--seed", str(len(uid)), *args, "-o", str(out)],
                       check=True, capture_output=True, timeout=120)
        uid[name] = read_log(out).hello["uid"]
    assert uid["reference"] == "e66038b7133a2b2f"
    assert len({uid["reference"], uid["a"], uid["b"]}) == 3, uid
    assert uid["a again"] == uid["a"], uid
