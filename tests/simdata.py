"""Simulated runs for the identification tests, made once per test session.

Everything goes through the real firmware on the simulated board and the
recorder, as a user's runs would; only the truth sidecar is test-only.
"""

from __future__ import annotations

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
    name = f"{manoeuvre}_{'+'.join(sorted(effects)) or 'clean'}_{seed}_{speed}_{abs(hash(key)) % 10**8}"
    mcap = root / f"{name}.mcap"
    csv_path = root / f"{name}.csv" if csv else None
    cfg = SimConfig(plan=Plan(name=manoeuvre, duration=duration, speed=speed, steer_amp=steer_amp,
                              bandwidth=bandwidth, speed_end=speed_end), effects=tuple(effects), seed=seed,
                    board=board, beta_sensor=beta_sensor, car=car or CarParams(), rate_hz=rate_hz)
    record(cfg, mcap, csv_path=csv_path, truth_path=root / f"{name}.truth.json")
    out = csv_path if csv else mcap
    _CACHE[key] = out
    return out


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
    mcap = root / f"random_steer_{Path(effect_file).stem}_{seed}_{speed}_{abs(hash(key)) % 10**8}.mcap"
    cfg = SimConfig(plan=Plan(name="random_steer", duration=duration, speed=speed, steer_amp=steer_amp,
                              bandwidth=bandwidth), effect_files=(str(effect_file),), seed=seed)
    record(cfg, mcap, truth_path=Path(str(mcap).rsplit(".", 1)[0] + ".truth.json"))
    _CACHE[key] = mcap
    return mcap
