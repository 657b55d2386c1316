"""Where the model misses when the data have no noise floor (held steer only: nothing says
what a correct model reaches), measured against the signal itself.

The data: tests/single_track_physics.py's 1:10 car driven by a teleoperator's held steer
(no random steer, so no floor), its road wheels following the steer through a 0.1 s servo
lag the plain bicycle lacks; and the same car without the lag, which the bicycle fits to the
noise.
"""

from __future__ import annotations

import re

import numpy as np
from scipy import signal

from single_track_physics import Car, drive, held_steer, log_csv
from stid.analysis.unexplained import where_without_floor
from stid.fit import dataset
from stid.fit.fitting import fit
from stid.load import load_runs
from stid.vehicle_file import load_vehicle

FS = 50.0
TAU = 0.1  # s, servo lag (HARDWARE.md: 0.05-0.16 s for RC servos)


def where(tmp_path, lag: bool):
    car = Car()
    rng = np.random.default_rng(11)
    asked = held_steer(60.0, FS, rng, amplitude=0.2)
    wheels = signal.lfilter(*signal.bilinear([1.0], [TAU, 1.0], fs=FS), asked) if lag else asked
    t = np.arange(len(asked)) / FS
    vx = 2.0 + 0.8 * np.sin(2 * np.pi * t / 15)
    ay, r, _ = drive(car, wheels, FS, vx)
    (tmp_path / "car.toml").write_text(car.toml())
    path = log_csv(tmp_path / "run.csv", t, asked, ay, r, vx, np.random.default_rng(12))
    vehicle = load_vehicle(tmp_path / "car.toml")
    runs = load_runs([path], vehicle)
    stretches = dataset.dynamic_stretches(runs)
    res = fit(runs, vehicle, "bicycle", "time", intervals="noise", stretches=stretches)
    return where_without_floor("bicycle", res, vehicle, stretches)


def test_a_missing_servo_lag_is_located_without_a_floor(tmp_path):
    lines = where(tmp_path, lag=True)
    assert any(line.startswith("r (no floor to judge it by): its error lies at") for line in lines), lines
    follows = [line for line in lines if "residual follows" in line]
    # a lag misses most where the steer moves: its strongest channel is the steer rate
    assert follows and any(re.match(r"the (ay|r) residual follows steer rate", line) for line in follows), lines


def test_a_model_that_is_right_follows_nothing_beyond_chance(tmp_path):
    lines = where(tmp_path, lag=False)
    assert not [line for line in lines if "residual follows" in line], lines
    assert not [line for line in lines if "grows faster than the signal" in line], lines
