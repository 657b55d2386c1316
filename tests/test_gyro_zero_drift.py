"""A gyro zeroed at a stand-still of the same run: an offset a fit names beyond that zero is at
most the gyro's drift since (stid.analysis.kinematics, rule 3).

At one speed the kinematics (ay = vy' + vx r) give one equation for two sensor offsets: a gyro
offset is hidden by an accelerometer offset of vx times it. A car with a steering trim and a
tilted accelerometer (the real FrictionMaps car's VESC sits tilted: ay -0.2 m/s^2 at rest) then
fits sensor offsets as well as a trim, and better, since they also take the tilt. The run's own
stand-still says the gyro reads true. Data written here from plain physics
(tests/single_track_physics.py: RK4 of the linear single track), apart from stid's models.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from single_track_physics import Car, drive, held_steer, log_csv
from stid.analysis.kinematics import GYRO_ZERO_DRIFT, Z, kinematic_veto
from stid.fit import dataset
from stid.load import load_runs
from stid.vehicle_file import load_vehicle

FS = 50.0
OFFSET = 0.02  # rad/s: the gyro's zero (1.1 deg/s); the loader takes it off at the stand-still
TRIM = 0.03  # rad at the road wheels: at 1.5 m/s the car yaws 0.13 rad/s (7.6 deg/s) at zero command
TILT = -0.2  # m/s^2: the accelerometer's offset in ay (a tilt of 1.2 deg)
GYRO_NOISE = 0.004  # rad/s rms (log_csv's default)


def zeroed_run(tmp_path, still_s=4.0, drive_s=40.0, gyro_drift=0.0, seed=7):
    """The car stands still ``still_s``, drives ``drive_s`` at 1.5 m/s on a teleoperator's held
    steer with the road wheels TRIM off the command, and stands still again; the accelerometer
    reads ay + TILT, the gyro r + OFFSET, growing by ``gyro_drift`` [rad/s] from the first
    stand-still to the last."""
    car = Car()
    rng = np.random.default_rng(seed)
    command = held_steer(drive_s, FS, rng, amplitude=0.12)
    ay, r, _ = drive(car, command + TRIM, FS, 1.5)
    n0 = int(still_s * FS)
    pad = lambda x: np.r_[np.zeros(n0), x, np.zeros(n0)]  # noqa: E731
    n = len(command) + 2 * n0
    t = np.arange(n) / FS
    gyro = OFFSET + gyro_drift * np.clip((t - still_s) / drive_s, 0.0, 1.0)
    (tmp_path / "car.toml").write_text(car.toml())
    path = log_csv(tmp_path / "run.csv", t, pad(command), pad(ay) + TILT, pad(r) + gyro, pad(np.full(len(ay), 1.5)),
                   np.random.default_rng(seed + 1), noise=(0.15, GYRO_NOISE, 0.02))
    return load_runs([path], load_vehicle(tmp_path / "car.toml")), load_vehicle(tmp_path / "car.toml")


def test_the_zero_says_what_it_rests_on(tmp_path):
    """The zero's standard error is the white noise's over the samples standing still; two
    stand-stills a run apart show how far the zero moved between them."""
    drift = 0.01
    (run,), _ = zeroed_run(tmp_path, gyro_drift=drift)
    zero = run.meta["gyro_zero"]
    assert zero["source"] == "this run's stand-still"
    n = zero["still_s"] * FS
    assert 4.0 < zero["still_s"] < 8.0, zero  # both stand-stills, less the second before driving off
    assert 0.6 < zero["stderr"] / (GYRO_NOISE / np.sqrt(n)) < 1.6, zero
    assert zero["value"] == pytest.approx(run.meta["gyro_bias"])
    assert zero["drift_seen"] == pytest.approx(drift, abs=6 * GYRO_NOISE / np.sqrt(n / 2)), zero


@pytest.fixture(scope="module")
def trimmed(tmp_path_factory):
    runs, vehicle = zeroed_run(tmp_path_factory.mktemp("trim"))
    return runs, vehicle, dataset.dynamic_stretches(runs)


def _bias_fit(vehicle, stretches, bias_r):
    """bicycle+sensor_bias with the gyro offset held at ``bias_r`` and the accelerometer's at what
    the data's kinematics then ask (mean ay - vx r = bias_ay - bias_r vx): offsets the kinematics
    at this one speed accept, whatever bias_r is."""
    from stid.analysis.kinematics import speed_groups
    from stid.fit.time_fit import fit_time
    from stid.models.model import Model

    (g,) = speed_groups(stretches)
    fixed = {"bias_r": bias_r, "bias_ay": g.k + bias_r * g.speed}
    return fit_time(Model("bicycle+sensor_bias", vehicle), stretches, fixed=fixed, intervals="noise")


def test_a_gyro_offset_beyond_the_zeros_drift_is_not_the_gyros(trimmed):
    runs, vehicle, stretches = trimmed
    allowed = GYRO_ZERO_DRIFT + Z * runs[0].meta["gyro_zero"]["stderr"]
    beyond = _bias_fit(vehicle, stretches, -2 * allowed)
    veto = kinematic_veto("sensor_bias", beyond, stretches)
    assert "the gyro was zeroed at this run's stand-still" in veto, veto
    within = _bias_fit(vehicle, stretches, 0.5 * GYRO_ZERO_DRIFT)
    assert kinematic_veto("sensor_bias", within, stretches) == ""
    # a run that never stood still has no zero to bound the gyro by: at one speed nothing rules it out
    unzeroed = [dataclasses.replace(s, gyro_zero=None) for s in stretches]
    assert kinematic_veto("sensor_bias", beyond, unzeroed) == ""


def test_a_trimmed_car_with_a_tilted_accelerometer_is_not_told_its_gyro_is_off(trimmed):
    """diagnose --peel on the trimmed car: sensor offsets fit a trim and a tilt at one speed, but a
    gyro offset of a trim's size (7.6 deg/s) is not named when the run's stand-still zeroed the gyro;
    whatever is named beyond the zero stays within the drift, and the trim is named as a trim."""
    from stid.diagnose import diagnose

    runs, vehicle, _ = trimmed
    rounds = diagnose(runs, vehicle, "bicycle", peel=True)
    named = [e for d in rounds for e in d.named]
    table = [[(c.effect, c.significant, c.why_not) for c in d.candidates] for d in rounds]
    assert "steer_offset" in named, table
    final = next(d.named_result for d in reversed(rounds) if d.best is not None)
    lo, hi = dict(zip(final.names, final.ci95))["delta0"]
    assert lo <= TRIM <= hi, final.table()
    if "sensor_bias" in named:
        allowed = GYRO_ZERO_DRIFT + Z * runs[0].meta["gyro_zero"]["stderr"]
        assert abs(final.value("bias_r")) <= allowed, final.table()


@pytest.mark.parametrize("reading", ["noise about 0", "its magnitude"])
def test_a_stand_still_whose_speed_reads_noise_is_one(tmp_path, reading):
    """An odometry or fused speed reads noise about zero at rest, not 0: a trial user's +-0.07 m/s
    (sd 0.02) split a 4 s stand-still, sample by sample against 0.05 m/s, into pieces under 0.5 s,
    and the run was said to stand still "for under 0.5 s, too little to show the gyro's zero"
    (the bias then left to a fit). It is now one stand-still, and the zero is taken from it."""
    (ref,), _ = zeroed_run(tmp_path)
    path = tmp_path / "run.csv"
    import pandas as pd

    df = pd.read_csv(path)
    rng = np.random.default_rng(5)
    at_rest = df["vx"].to_numpy() == 0.0
    noise = 0.02 * rng.standard_normal(int(at_rest.sum()))
    df.loc[at_rest, "vx"] = noise if reading == "noise about 0" else np.abs(noise)
    df.to_csv(path, index=False, float_format="%.7g")
    (run,) = load_runs([path], load_vehicle(tmp_path / "car.toml"))
    zero = run.meta.get("gyro_zero")
    assert zero is not None, run.meta["notes"]
    assert zero["still_s"] == pytest.approx(ref.meta["gyro_zero"]["still_s"], abs=0.3), (zero, ref.meta["gyro_zero"])
    assert zero["value"] == pytest.approx(OFFSET, abs=4 * zero["stderr"]), zero
