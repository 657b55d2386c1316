"""What a run that is still being written holds so far, and what is wrong with it, in words.

A stid-log file is flushed every second and read up to its last complete chunk (as
``stid fit`` reads a file cut short); a ROS 2 bag being recorded is read once the loader
can read it. Nothing here raises for a file that is merely not ready: the live view says
what it waits for and keeps going.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from host.errors import HostError
from stid.errors import StidError

# No new sample for this long, while the file is not finished: the port has gone quiet.
QUIET_S = 3.0
# Events of the logger worth a line in the live view (host.link_watch, host.logger).
_SHOWN_EVENTS = ("disconnect", "reconnect", "restart", "boot", "silence", "rejects", "no_hello", "hello")


@dataclass
class Snapshot:
    """The runs so far (possibly none) and what the view should say about the data."""

    runs: list = field(default_factory=list)
    samples: int = 0
    seconds: float = 0.0  # seconds of samples in the runs
    state: list = field(default_factory=list)  # what is missing or wrong, in words (empty: all well)
    events: list = field(default_factory=list)  # (seconds into the run, event, detail), the logger's
    link: dict = field(default_factory=dict)  # the logger's last statistics (lost frames, ...)
    finished: bool = False  # the logger closed the file: no more data will come
    changed: bool = True  # the file changed since the previous snapshot
    read_s: float = 0.0  # CPU seconds reading it took


class Source:
    """A run file that grows. ``poll()`` gives the newest snapshot; an unchanged file is not
    read again."""

    def __init__(self, path, vehicle):
        self.path = Path(path)
        self.vehicle = vehicle
        self._sig = None
        self._last = Snapshot(state=[f"waiting for {self.path} to appear"])
        self._last_growth = time.monotonic()
        self._grew_at = time.time()
        self._samples = -1
        self._chunks: dict = {}  # what the file's chunks held at earlier reads (they never change)
        self._tmp = None  # a directory for the readable copy of a ROS 2 bag being recorded

    def poll(self) -> Snapshot:
        sig = _signature(self.path)
        now = time.monotonic()
        if sig is not None and sig == self._sig:
            snap = self._last
            snap.changed = False
        else:
            self._sig = sig
            cpu = time.process_time()
            snap = self._read() if sig is not None else Snapshot(state=[f"waiting for {self.path} to appear"])
            snap.read_s = time.process_time() - cpu
            self._last = snap
        if snap.samples != self._samples:
            self._samples = snap.samples
            self._last_growth = now
            self._grew_at = time.time()
        quiet = now - self._last_growth
        snap.state = [s for s in snap.state if not s.startswith("no new samples")]
        if not snap.finished and quiet >= QUIET_S and snap.samples:
            # (the clock time it stopped, not a count of seconds: a line that changed every update had
            # a piped view print its whole block again every 2 s while the port was quiet)
            since = time.strftime("%H:%M:%S", time.localtime(self._grew_at))
            snap.state.append(f"no new samples since {since}: the port has gone quiet (car off, out of range, "
                              "unplugged?); the view goes on with what it has")
        return snap

    def _read(self) -> Snapshot:
        from host.mcap_scan import holds_a_log
        from stid.ros import bag as ros_bag

        if self.path.is_file() and self.path.stat().st_size == 0:
            return Snapshot(state=[f"{self.path.name} is empty so far: waiting for the logger's first flush"])
        if self.path.is_dir() or ros_bag.kind_of(self.path) or not holds_a_log(self.path):
            return self._read_other()  # a ROS bag, a CSV: what the loader makes of it
        return self._read_stid_log()

    def _read_other(self) -> Snapshot:
        """A ROS bag (or a CSV): the loader's runs once it can read them; a ROS 2 bag still
        being recorded through a finished copy of its complete chunks."""
        from stid.ros.unclosed import being_recorded, readable_copy
        from stid.load import load_runs

        path = self.path
        inside = sorted(path.glob("*.mcap")) if path.is_dir() and not (path / "metadata.yaml").exists() else []
        if len(inside) == 1:  # a bag directory whose metadata rosbag2 has not written yet: its one file
            path = inside[0]
        recording = being_recorded(path)
        if path.suffix.lower() == ".csv":
            path = self._whole_lines(path)  # a logger appending rows: its last one may be half written
        if recording is not None:
            path = self._scratch() / recording.name
            if not readable_copy(recording, path):
                return Snapshot(state=[f"{recording.name}: no complete chunk yet (ros2 bag record writes them "
                                       "as it goes); waiting"])
        try:
            runs = load_runs([path], self.vehicle)
        except (StidError, HostError) as e:
            return Snapshot(state=[f"{self.path.name} is not readable yet ({_first_sentence(e)}); trying again"])
        except Exception as e:  # noqa: BLE001 -- a bag half written can break its reader anywhere
            return Snapshot(state=[f"{self.path.name} is not readable yet ({type(e).__name__}: {e}); trying again"])
        snap = _with_runs(Snapshot(), runs)
        if recording is not None:
            for r in runs:
                r.name = r.name.replace(path.name, recording.name)
            snap.state.append("a ROS 2 bag being recorded: read up to its last complete chunk")
        return snap

    def _scratch(self) -> Path:
        """A directory of the view's own, for readable copies of what is being written."""
        if self._tmp is None:
            import tempfile

            self._tmp = tempfile.TemporaryDirectory(prefix="stid-live-")
        return Path(self._tmp.name)

    def _whole_lines(self, path: Path) -> Path:
        """A CSV up to its last complete line (a copy, when the last line is not complete)."""
        data = path.read_bytes()
        end = data.rfind(b"\n") + 1
        if end == len(data):
            return path
        copy = self._scratch() / path.name
        copy.write_bytes(data[:end])
        return copy

    def _read_stid_log(self) -> Snapshot:
        from host.mcap_read import read_log
        from stid.load import MIN_SAMPLES, load_mcap

        snap = Snapshot()
        try:
            log = read_log(self.path, self._chunks)
        except HostError as e:
            snap.state.append(f"{self.path.name} is not readable yet ({_first_sentence(e)}); trying again")
            return snap
        snap.finished = "stid.stats" in log.metadata
        snap.link = log.stats or {}
        lost = snap.link.get("lost_frames", 0) if isinstance(snap.link, dict) else 0
        if lost:
            snap.state.append(f"the link lost {lost} frames so far (left out of the fit, never guessed): a loose "
                              "cable or a noisy radio link?")
        t0 = int(log.samples["t_host_ns"][0]) if len(log.samples) else None
        for ns, doc in log.events:
            if doc.get("event") in _SHOWN_EVENTS:
                at = (ns - t0) / 1e9 if t0 is not None else 0.0
                snap.events.append((at, doc.get("event"), doc.get("detail", "")))
        snap.samples = len(log.samples)
        if not snap.samples:
            snap.state.append("no samples yet: is the car powered and the firmware running?")
            return snap
        if not log.hello:
            snap.state.append(f"no HELLO from the board yet ({snap.samples} samples held: their ADC scale is unknown "
                              "until one arrives; the board sends one every 1-2 s)")
            return snap
        if snap.samples < MIN_SAMPLES:
            snap.state.append(f"{snap.samples} samples so far: waiting for more")
            return snap
        try:
            runs = load_mcap(self.path, self.vehicle, log=log)
        except StidError as e:
            snap.state.append(f"not usable yet: {_first_sentence(e)}")
            return snap
        last = snap.events[-1] if snap.events else None
        if last is not None and last[1] == "disconnect" and not snap.finished:
            snap.state.append(f"the port went away at {last[0]:.0f} s; the logger waits for the same board")
        return _with_runs(snap, runs)


def _with_runs(snap: Snapshot, runs: list) -> Snapshot:
    snap.runs = runs
    snap.samples = snap.samples or sum(len(r.t) for r in runs)
    snap.seconds = sum(len(r.t) / r.fs for r in runs)
    return snap


def _signature(path: Path):
    """What changes when the file (or a bag directory's files) is written to."""
    try:
        if path.is_dir():
            return tuple(sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in path.iterdir()))
        st = os.stat(path)
        return st.st_size, st.st_mtime_ns
    except OSError:
        return None


def _first_sentence(e: Exception) -> str:
    text = str(e)
    return text.split("; ")[0] if len(text) > 160 else text
