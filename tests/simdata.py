"""Simulated runs for the identification tests, made once per test session.

Everything goes through the real firmware on the simulated board and the
recorder, as a user's runs would; only the truth sidecar is test-only.

Under pytest-xdist the workers share one directory (``conftest.simdir``): the first worker
to need a run records it, one that needs it meanwhile waits for it (an ``flock`` on the
run's lock file) and reads it. Each worker recorded its own copy before: 91 s of the
suite's 278 s of simulation were the same runs again.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
from pathlib import Path

from hil_sim.manoeuvres import Plan
from hil_sim.record import record
from hil_sim.run import SimConfig
from hil_sim.vehicle import CarParams

_CACHE: dict = {}
TRUTH = CarParams()


def sim_run(root: Path, manoeuvre: str = "random_steer", effects=(), seed: int = 1, speed: float = 4.0,
            duration: float = 40.0, steer_amp: float = 0.04, bandwidth: float = 4.0, csv: bool = False,
            beta_sensor: float | None = None, board: str = "pico", speed_end: float | None = None,
            car: CarParams | None = None, rate_hz: int = 500) -> Path:
    key = (manoeuvre, tuple(sorted(effects)), seed, speed, duration, steer_amp, bandwidth, csv, beta_sensor,
           board, speed_end, repr(car), rate_hz)
    if key in _CACHE:
        return _CACHE[key]
    name = f"{manoeuvre}_{'+'.join(sorted(effects)) or 'clean'}_{seed}_{speed}_{_digest(key)}"
    mcap = root / f"{name}.mcap"
    csv_path = root / f"{name}.csv" if csv else None
    cfg = SimConfig(plan=Plan(name=manoeuvre, duration=duration, speed=speed, steer_amp=steer_amp,
                              bandwidth=bandwidth, speed_end=speed_end), effects=tuple(effects), seed=seed,
                    board=board, beta_sensor=beta_sensor, car=car or CarParams(), rate_hz=rate_hz)
    _once(mcap, lambda: record(cfg, mcap, csv_path=csv_path, truth_path=root / f"{name}.truth.json"))
    out = csv_path if csv else mcap
    _CACHE[key] = out
    return out


def _digest(key) -> str:
    """The same in every worker (``hash`` of a string is salted per process)."""
    return hashlib.sha1(repr(key).encode()).hexdigest()[:10]


def _once(mcap: Path, make) -> None:
    """Record ``mcap`` unless a worker of this session has (its ``.done`` marker); a worker
    recording it holds the lock, so the others wait for the run instead of recording it too.
    A worker that dies mid-run releases the lock without the marker: the next one records."""
    done = mcap.with_name(mcap.name + ".done")
    with open(mcap.with_name(mcap.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            make()
            done.touch()


def truth(path: Path) -> dict:
    return json.loads(Path(str(path).rsplit(".", 1)[0] + ".truth.json").read_text())


def random_steer_pair(root: Path, effects=(), seeds=(1, 2), **kw) -> list[Path]:
    """The standard data set: random steer at 4 and 6 m/s, 40 s each."""
    return [sim_run(root, "random_steer", effects, seed=seeds[0], speed=4.0, **kw),
            sim_run(root, "random_steer", effects, seed=seeds[1], speed=6.0, **kw)]


def effect_file_run(root: Path, effect_file: Path, seed: int = 1, speed: float = 4.0, duration: float = 40.0,
                    steer_amp: float = 0.04, bandwidth: float = 4.0) -> Path:
    """A random-steer run with a user's truth-side effect file hidden in the car (stid-sim --effect-file)."""
    key = ("effect_file", str(effect_file), seed, speed, duration, steer_amp, bandwidth)
    if key in _CACHE:
        return _CACHE[key]
    mcap = root / f"random_steer_{Path(effect_file).stem}_{seed}_{speed}_{_digest(key)}.mcap"
    cfg = SimConfig(plan=Plan(name="random_steer", duration=duration, speed=speed, steer_amp=steer_amp,
                              bandwidth=bandwidth), effect_files=(str(effect_file),), seed=seed)
    _once(mcap, lambda: record(cfg, mcap, truth_path=Path(str(mcap).rsplit(".", 1)[0] + ".truth.json")))
    _CACHE[key] = mcap
    return mcap
