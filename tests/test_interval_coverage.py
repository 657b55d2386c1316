"""Intervals that hold the truth on cars other than the reference one, and on weak runs.

The simulator takes another car's truth from a TOML file (``stid-sim --car FILE``, read by
hil_sim itself); the identifier is told only what a user measures (mass, a, b, wheel
radius). Runs go through the real firmware at 100 Hz, as a small logger would take them.
Coverage over >= 30 seeds per case is under ``slow``; the default suite has three seeds of
the 1:5 car, which a coverage near 95% passes and one near 50% fails.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import tool
from hil_sim.car_file import load_car
from hil_sim.vehicle import CarParams
from simdata import sim_run
from stid.fit.fitting import fit
from stid.load import load_runs
from stid.vehicle_file import Vehicle

# A 1:10 car (F1TENTH class: 3.5-3.9 kg, Iz 0.047-0.063 kg m^2, normalised cornering
# stiffness 4-10 /rad) and a 1:5 car (~24 kg, 0.58 m wheelbase). Relaxation lengths about
# a wheel radius (HARDWARE.md); both understeer, as RC cars are set up to.
CARS = {
    "tenth": {"mass": 3.7, "a": 0.15, "b": 0.18, "Iz": 0.05, "Cf": 140.0, "Cr": 150.0, "wheel_radius": 0.05,
              "track": 0.20, "sigma_f": 0.05, "sigma_r": 0.05},
    "fifth": {"mass": 24.0, "a": 0.31, "b": 0.27, "Iz": 1.0, "Cf": 770.0, "Cr": 1130.0, "wheel_radius": 0.09,
              "track": 0.40, "sigma_f": 0.10, "sigma_r": 0.10},
}
RELAXED = ("Cf", "Cr", "Iz", "sigma_f", "sigma_r")
CASES = {
    # car, firmware rate [Hz], hidden effects, speed [m/s], seconds, steer rms [rad], model, parameters
    "tenth_100Hz_relaxation": ("tenth", 100, ("tyre_relaxation",), 4.0, 40.0, 0.04, "bicycle+tyre_relaxation", RELAXED),
    "fifth_100Hz_relaxation": ("fifth", 100, ("tyre_relaxation",), 5.0, 40.0, 0.04, "bicycle+tyre_relaxation", RELAXED),
    "weak_reference": (None, 500, (), 4.0, 20.0, np.radians(0.3), "bicycle", ("Cf", "Cr", "Iz")),
    "weak_tenth_100Hz": ("tenth", 100, (), 4.0, 20.0, np.radians(0.3), "bicycle", ("Cf", "Cr", "Iz")),
}


def car_file(root: Path, name: str) -> Path:
    path = root / f"{name}.toml"
    if not path.exists():
        path.write_text("".join(f"{k} = {v!r}\n" for k, v in CARS[name].items()))
    return path


def vehicle_of(name: str | None) -> Vehicle:
    """What a user gives stid: scales, a tape, the wheel radius (never the truth's Iz or Cf)."""
    c = CARS[name] if name else CarParams().as_dict()
    return Vehicle(name or "reference", c["mass"], c["a"], c["b"], wheel_radius=c["wheel_radius"])


def covered(root: Path, case: str, seed: int) -> dict:
    """Per parameter: does the fit's 95% interval hold the truth on this seed's run?"""
    car, rate, effects, speed, seconds, amp, model, names = CASES[case]
    truth = load_car(car_file(root, car)) if car else CarParams()
    path = sim_run(root, "random_steer", effects, seed=seed, speed=speed, duration=seconds, steer_amp=amp,
                   car=truth, rate_hz=rate)
    v = vehicle_of(car)
    res = fit(load_runs([path], v), v, model, "time")
    assert res.converged, res.table()
    out = {}
    for n in names:
        ci = res.interval_of(n)
        out[n] = ci is not None and ci[0] <= getattr(truth, n) <= ci[1]
    return out


def coverage(root: Path, case: str, seeds) -> tuple[dict, list]:
    hits = [covered(root, case, s) for s in seeds]
    names = hits[0].keys()
    return {n: float(np.mean([h[n] for h in hits])) for n in names}, hits


def test_stid_sim_takes_another_car_from_a_file(tmp_path):
    """--car: the run's truth is the file's car (and the rest the reference car's)."""
    import json

    path = car_file(tmp_path, "fifth")
    out = tmp_path / "fifth.mcap"
    r = subprocess.run([tool("stid-sim"), "--fast", "--car", str(path), "--rate", "100", "--duration", "4",
                        "--effects", "tyre_relaxation", "-o", str(out), "--truth", str(tmp_path / "t.json")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    car = json.loads((tmp_path / "t.json").read_text())["car"]
    for k, v in CARS["fifth"].items():
        assert car[k] == v, k
    assert car["steer_us_per_rad"] == CarParams().steer_us_per_rad
    assert json.loads((tmp_path / "t.json").read_text())["rate_hz"] == 100


@pytest.mark.parametrize("text, words", [
    ("mass = 24\nIzz = 1.0\n", ["unknown key 'Izz'", "did you mean 'Iz'"]),
    ("mass = -3\n", ["mass must be positive"]),
    ("Cf = \"stiff\"\n", ["Cf must be a number"]),
    ("mass = \n", ["not valid TOML"]),
])
def test_a_car_file_that_cannot_be_a_car_is_refused(tmp_path, text, words):
    path = tmp_path / "car.toml"
    path.write_text(text)
    with pytest.raises(ValueError) as e:
        load_car(path)
    assert all(w in str(e.value) for w in words), e.value


def test_stid_sim_refuses_a_bad_car_file_in_one_line_before_it_runs(tmp_path):
    path = tmp_path / "car.toml"
    path.write_text("mass = 24\nIzz = 1.0\n")
    r = subprocess.run([tool("stid-sim"), "--fast", "--car", str(path), "-o", str(tmp_path / "x.mcap")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Izz" in r.stderr, r.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_a_5th_scale_car_at_100_hz_three_seeds(simdir):
    """Three seeds of the 1:5 car with relaxation at 100 Hz: each parameter's interval holds the
    truth in at least two (at 95% coverage all three do 86% of the time, at 50% coverage
    two or three only half the time)."""
    cov, hits = coverage(simdir, "fifth_100Hz_relaxation", (901, 902, 903))
    assert min(cov.values()) >= 2 / 3, hits


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_intervals_hold_the_truth_in_90_percent_of_30_seeds(simdir, case):
    cov, hits = coverage(simdir, case, range(1000, 1030))
    assert min(cov.values()) >= 0.9, (cov, [i for i, h in enumerate(hits) if not all(h.values())])
