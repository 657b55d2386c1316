"""Runs of any single-track car straight from the truth dynamics, as CSV in the
import contract with measurement noise but no scale-car electronics: for cars
instrumented otherwise (the passenger car of study 1: steering robot, gyro,
accelerometer and an optical body-slip sensor)."""

from __future__ import annotations

import numpy as np

from hil_sim import manoeuvres, vehicle
from hil_sim.record import write_columns


def truth_run(car: vehicle.CarParams, effects, plan: manoeuvres.Plan, fs: float = 100.0, seed: int = 0,
              noise: dict | None = None, dt: float = 1e-3) -> dict:
    """Columns t, steer, ay, r, vx, beta sampled at fs with white noise of the given rms."""
    noise = {"steer": 2e-4, "ay": 0.05, "r": 0.002, "vx": 0.02, "beta": 5e-4, **(noise or {})}
    rng = np.random.default_rng(seed)
    man = manoeuvres.build(plan, dt, rng)
    tr = vehicle.simulate(car, vehicle.Effects(set(effects)), man.t, man.delta_cmd, man.v_ref)
    t = np.arange(0, tr.t[-1], 1.0 / fs)
    beta = np.arctan2(tr.vy, np.maximum(tr.vx, 0.1))
    cols = {"t": t}
    for name, x in (("steer", tr.delta_cmd), ("ay", tr.ay), ("r", tr.r), ("vx", tr.vx), ("beta", beta)):
        cols[name] = np.interp(t, tr.t, x) + noise[name] * rng.standard_normal(len(t))
    return cols


def write_truth_run(path, *args, **kw) -> None:
    write_columns(path, truth_run(*args, **kw))
