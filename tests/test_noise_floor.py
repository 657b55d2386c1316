"""The noise floor tells a wrong model it misses something, also where the car is not a linear
response to the logged steer: a servo trim at a swinging speed, and tyres that near their grip. Data
written from plain physics (tests/test_trim_and_gyro.py's trimmed single track, integrated by
Runge-Kutta; tests/test_convergence.py's tanh-tyre single track), not the project's simulator.

Before the predictor carried the trim's speed-dependent offset and the steer's cube, the floor
sat below what the right model reaches (15.5 points with the trim, 11.4 with these tyres), so a fit
of the wrong model, that many points short, was not told it missed something."""

from __future__ import annotations

import dataclasses

from stid.analysis.noise_floor import below_floor, noise_floor_uncertainty
from stid.fit import dataset
from stid.fit.fitting import fit
from stid.load import load_runs
from test_convergence import CAR, tanh_car_run
from test_trim_and_gyro import plain_run
from stid.vehicle_file import Vehicle

OUTS = ("ay", "r")


def _short_of_the_floor(runs, vehicle, wrong: str):
    """(floor, its standard error, how far the model ``wrong`` is below it where that is told)."""
    floor, se = noise_floor_uncertainty(dataset.dynamic_stretches(runs))
    return floor, se, below_floor(fit(runs, vehicle, wrong, "time"), floor, se)


def test_a_trim_at_a_swinging_speed_is_inside_the_floor(tmp_path, rc_vehicle):
    vehicle = dataclasses.replace(rc_vehicle, sensors={**rc_vehicle.sensors, "accel_bandwidth_hz": 0.0,
                                                       "gyro_bandwidth_hz": 0.0})
    runs = load_runs([plain_run(tmp_path / f"run{k}.csv", k + 1, v, trim=0.03, swing=0.25)
                      for k, v in enumerate((4.0, 6.0))], vehicle)
    floor, se, short = _short_of_the_floor(runs, vehicle, "bicycle")
    assert short and max(short.values()) > 2.0, (floor, short)  # the model without the trim is told
    good = fit(runs, vehicle, "bicycle+steer_offset", "time")
    for o in OUTS:  # and the right model does not beat the floor beyond its error
        assert good.fit[o] <= floor[o] + 3 * se[o] + 0.1, (o, good.fit, floor, se)


def test_a_model_without_the_tyres_saturation_is_told_it_is_short():
    vehicle = Vehicle("tenth", CAR["mass"], CAR["a"], CAR["b"], sensors={"accel_bandwidth_hz": 0.0,
                                                                         "gyro_bandwidth_hz": 0.0})
    runs = [tanh_car_run(seed=1), tanh_car_run(seed=2, name="tanh2")]
    # (the floor rose from ay 88.0% to 96.0% here; the right model fits 99.4%: a saturation that
    # follows the slip, not the steer, is more than a cube of the steer shows, and beats the floor)
    floor, _, short = _short_of_the_floor(runs, vehicle, "bicycle")
    assert short and max(short.values()) > 2.0, (floor, short)


def test_one_run_that_holds_two_speeds_has_the_floor_the_right_model_reaches(tmp_path, rc_vehicle):
    """One run, 28 s at 3 m/s then 28 s at 6 m/s (a trial user's two-speed runs): one predictor
    about its median speed could not span both, and the floor sat 1-2.4 points below what the
    right model reached, +-1.1 to 1.6 (here, seeds 3-5: 0.3-0.7 points below, +-0.46 to 0.84).
    Each held speed is predicted on its own now (0.04-0.1 below, +-0.04 to 0.12)."""
    import numpy as np

    vehicle = dataclasses.replace(rc_vehicle, sensors={**rc_vehicle.sensors, "accel_bandwidth_hz": 0.0,
                                                       "gyro_bandwidth_hz": 0.0})
    two = plain_run(tmp_path / "two.csv", 3, lambda t: np.interp(t, [0, 28, 32, 60], [3.0, 3.0, 6.0, 6.0]),
                    duration=60.0, fs=100.0)
    runs = load_runs([two], vehicle)
    floor, se = noise_floor_uncertainty(dataset.dynamic_stretches(runs))
    right = fit(runs, vehicle, "bicycle", "time")
    for o in OUTS:  # the right model neither beats the floor nor falls short of it beyond its error
        assert abs(right.fit[o] - floor[o]) <= max(0.3, 3 * se[o]), (o, right.fit, floor, se)
        assert se[o] < 0.3, (o, floor, se)


def test_short_runs_with_slow_coloured_noise_leave_the_right_model_at_its_floor(tmp_path):
    """12 s runs whose sensor noise is coloured below 1 Hz (a trial user's car, plain physics): the
    floor read 1.6 points (ay) above the right model's fit on average, and 6 of 30 such right fits
    were told they were far below it, that is, missing an effect they did not miss. The predictor's
    own estimation error had been taken off as sigma^2 p tau / n with tau the noise's autocorrelation
    time, far more than the estimation error is where the steer's colour differs from the noise's.
    Here the right model's fit sits at the floor (the gaps' mean within half a point; each fit not
    told it is short)."""
    import numpy as np
    from scipy import signal

    from test_track_runs import A, B, M, bicycle_run, write_csv

    vehicle = Vehicle("test car", M, A, B, sensors={"accel_bandwidth_hz": 0.0, "gyro_bandwidth_hz": 0.0})
    sos = signal.butter(4, 1.0, fs=200.0, output="sos")
    gaps, told = [], []
    for seed in range(6):
        run = bicycle_run(lambda t: np.full_like(t, 4.0), T=13.0, seed=seed)
        rng = np.random.default_rng(100 + seed)
        for out, share in (("ay", 0.05), ("r", 0.02)):  # the trial's levels: fits of ~95% and ~98%
            slow = signal.sosfilt(sos, rng.standard_normal(len(run["t"]) + 2000))[2000:]
            run[out] = run[out] + share * np.std(run[out]) * slow / np.std(slow)
        path = tmp_path / f"run{seed}.csv"
        write_csv(path, run)
        runs = load_runs([path], vehicle)
        stretches = dataset.dynamic_stretches(runs)
        floor, se = noise_floor_uncertainty(stretches)
        res = fit(runs, vehicle, "bicycle", "time", stretches=stretches)
        gaps.append([floor[o] - res.fit[o] for o in OUTS])
        told.append(below_floor(res, floor, se))
    mean = np.mean(gaps, axis=0)
    assert np.all(np.abs(mean) < 0.5), (mean, gaps)
    assert not any(told), told


def test_a_fit_a_little_below_the_floor_beyond_chance_is_told_a_small_effect_may_be_missing(tmp_path):
    """An accelerometer off the CG (plain physics: ay + x r') leaves the bicycle 1-2 points below the
    floor, many of the floor's standard errors: a trial's `stid fit` said nothing there in 28 of 40
    runs (its warning starts at 2 points), while diagnose named the offset to the millimetre. Now the
    fit says a small effect may be missing and points to diagnose; the right model, on the same run
    without the offset, is not told so. The JSON carries both gaps and the floor's above. (On this
    9 kg car 10 cm ahead gives 1.1 points at 20 standard errors; 5 cm, none: the bicycle takes it up.)"""
    import json
    import subprocess
    import sys

    import numpy as np

    from test_track_runs import A, B, M, bicycle_run, write_csv

    car = tmp_path / "car.toml"
    car.write_text(f'name = "test car"\nmass = {M}\na = {A}\nb = {B}\n[sensors]\naccel_bandwidth_hz = 0\n'
                   'gyro_bandwidth_hz = 0\n')
    run = bicycle_run(lambda t: np.full_like(t, 4.0), T=40.0, seed=5)
    rng = np.random.default_rng(5)
    noise = {o: 0.04 * np.std(run[o]) * rng.standard_normal(len(run["t"])) for o in ("ay", "r")}
    docs = {}
    for name, x_acc in (("right", 0.0), ("offset", 0.10)):
        cols = dict(run, ay=run["ay"] + x_acc * np.gradient(run["r"], run["t"]) + noise["ay"], r=run["r"] + noise["r"])
        write_csv(tmp_path / f"{name}.csv", cols)
        out = subprocess.run([sys.executable, "-m", "stid.cli", "fit", str(tmp_path / f"{name}.csv"), "--vehicle",
                              str(car), "--json"], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        docs[name] = json.loads(out.stdout)
    right, offset = docs["right"], docs["offset"]
    assert right["below_floor"] == right["below_floor_small"] == right["above_floor"] == {}, right
    assert not right["below_floor"] and "ay" in offset["below_floor_small"], offset["below_floor_small"]
    assert 0.5 < offset["below_floor_small"]["ay"] <= 2.0
    assert any("a small effect may be missing" in n and "stid diagnose" in n for n in offset["notes"]), offset["notes"]
