"""Loading a ROS 2 bag as a user meets it: a 10-minute drive of an F1TENTH-class car (IMU
200 Hz, odometry 50 Hz, Ackermann command 50 Hz: 180,000 messages), in the file
``ros2 bag record -s mcap`` makes (libmcap's defaults: zstd chunks of ~768 KiB with
CRCs, profile ``ros2``), loaded into a run by a fresh process (imports included).

The drive is the test suite's plain-physics car (tests/ros_data.py), written with
rosbags' writer and then re-chunked by the mcap library as libmcap writes."""

from __future__ import annotations

import importlib.util
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _ros_data():
    spec = importlib.util.spec_from_file_location("ros_data", REPO / "tests" / "ros_data.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["ros_data"] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def make_bag(data_dir: Path, minutes: float) -> tuple[Path, Path]:
    """The bag and its vehicle file (kept in ``data_dir`` between runs)."""
    rd = _ros_data()
    name = f"f1tenth_{minutes:g}min"
    bag = data_dir / f"{name}.mcap"
    car = rd.vehicle_toml(data_dir / f"{name}.toml")
    if not bag.exists():
        raw = data_dir / f"{name}_rosbags"
        if raw.exists():
            import shutil

            shutil.rmtree(raw)
        rd.write_bag(rd.drive(duration=minutes * 60.0), raw, rd.Layout())
        rd.as_libmcap_writes(rd.ros2_mcap(raw), bag)
    return bag, car


# the loading alone, timed inside the process, after its imports
_LOAD = ("import sys, time; from stid.load import load_file; from stid.vehicle_file import load_vehicle; "
         "v = load_vehicle(sys.argv[2]); t0 = time.perf_counter(); runs = load_file(sys.argv[1], v); "
         "print(time.perf_counter() - t0, sum(len(r.t) for r in runs))")


def load_time(data_dir: Path, quick: bool) -> dict:
    """Wall time (best of 3: the least disturbed by other programs) and CPU time (median; the
    child's, from its rusage: on a shared machine the wall time also counts the other
    programs' turns) of a whole process loading the bag."""
    import os
    import resource

    minutes = 1 if quick else 10
    bag, car = make_bag(Path(data_dir), minutes)
    walls, cpus, inner = [], [], []
    samples = 0
    for _ in range(3):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", _LOAD, str(bag), str(car)], capture_output=True, text=True,
                           check=True)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
        seconds, samples = p.stdout.split()
        inner.append(float(seconds))
    return {"minutes": minutes, "file_mb": bag.stat().st_size / 1e6, "samples": int(samples),
            "messages": int(minutes * 60 * 300), "wall_s": min(walls),
            "cpu_s": statistics.median(cpus), "in_process_s": statistics.median(inner),
            "load_avg": os.getloadavg()[0], "cores": os.cpu_count()}
