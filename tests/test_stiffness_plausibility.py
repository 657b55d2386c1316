"""A fitted axle stiffness that no tyre has, the steering calibration measured from the car's
own held steer, and a steer column that piles up at its clip.

The data are written here from plain physics (tests/single_track_physics.py: a 1:10 car with
normalised cornering stiffness 6 and 7 /rad, driven slowly by a teleoperator's held steer),
and what the log says is changed the way real logs are wrong: the steer column 1/0.6 of the
road-wheel angle, a command clipped at its limit, a clip in the logging that the wheels went
beyond. The real FrictionMaps log (tests/fixtures/real/frictionmaps) is judged by what its
own numbers say, never by a tuned value.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from single_track_physics import Car, drive, held_steer, log_csv
from stid.analysis import held_steer as held
from stid.fit.fitting import fit
from stid.fit.plausibility import PLAUSIBLE_PER_RAD, axle_loads
from stid.load import load_runs
from stid.vehicle_file import load_vehicle

FS = 50.0
STILL_S = 3.0
REAL = __import__("conftest").REPO / "tests" / "fixtures" / "real" / "frictionmaps"


def teleop_log(tmp_path, name, car=None, seed=1, duration=60.0, speed=1.3, logged=lambda d: d, wheels=lambda d: d,
               amplitude=0.25, levels=None):
    """A slow teleoperated run: ``wheels`` maps the operator's steer to the road-wheel angle,
    ``logged`` to what the steer column holds. Returns (csv path, vehicle, the logged steer)."""
    car = car or Car()
    rng = np.random.default_rng(seed)
    asked = held_steer(duration, FS, rng, amplitude=amplitude, levels=levels)
    t = np.arange(len(asked)) / FS
    vx = speed * (1 + 0.12 * np.sin(2 * np.pi * t / 17))
    ay, r, _ = drive(car, wheels(asked), FS, vx)
    n0 = int(STILL_S * FS)
    pad = lambda x: np.r_[np.zeros(n0), x]  # noqa: E731  (standing still: nothing moves)
    steer = pad(logged(asked))
    path = log_csv(tmp_path / f"{name}.csv", np.arange(len(steer)) / FS, steer, pad(ay), pad(r), pad(vx),
                   np.random.default_rng(seed + 100))
    (tmp_path / "car.toml").write_text(car.toml())
    return path, load_vehicle(tmp_path / "car.toml"), steer


def stiffness_line(result):
    lines = [w for w in result.warnings if "axle's load" in w]
    assert len(lines) <= 1, lines
    return lines[0] if lines else None


def test_a_steer_column_logged_too_large_is_said_as_the_steering_calibration(tmp_path):
    """The column is 1/0.6 of the road-wheel angle (a [steering] gain that is off): the linear
    model answers with tyres no car has, and the line says the wheels turn ~0.6 of the steer."""
    path, vehicle, _ = teleop_log(tmp_path, "gain", logged=lambda d: d / 0.6)
    res = fit(load_runs([path], vehicle), vehicle, "bicycle", "auto")
    line = stiffness_line(res)
    assert line is not None, res.warnings
    c_front = res.value("Cf") / axle_loads(vehicle)["Cf"]
    assert c_front < PLAUSIBLE_PER_RAD[0], c_front  # the premise: soft beyond any tyre
    m = re.search(r"The wheels turn ([0-9.]+) of the logged steer", line)
    assert m, line
    assert float(m.group(1)) == pytest.approx(0.6, abs=0.05), line
    assert "[steering] gain" in line


def test_the_same_car_logged_right_gets_no_stiffness_line_and_a_gain_of_one(tmp_path):
    path, vehicle, _ = teleop_log(tmp_path, "true")
    runs = load_runs([path], vehicle)
    res = fit(runs, vehicle, "bicycle", "auto")
    assert stiffness_line(res) is None, res.warnings
    for name in ("Cf", "Cr"):
        c = res.value(name) / axle_loads(vehicle)[name]
        assert PLAUSIBLE_PER_RAD[0] <= c <= PLAUSIBLE_PER_RAD[1], (name, c)
    gain = held.steering_gain(runs, vehicle.L, PLAUSIBLE_PER_RAD)
    assert gain.gain == pytest.approx(1.0, abs=0.05), gain
    assert not gain.far_from_one()


@pytest.mark.parametrize("c_front, c_rear", [(PLAUSIBLE_PER_RAD[0], PLAUSIBLE_PER_RAD[1]),
                                             (PLAUSIBLE_PER_RAD[1], PLAUSIBLE_PER_RAD[0])])
def test_tyres_at_the_ends_of_the_plausible_range_stay_inside_the_band_they_give(tmp_path, c_front, c_rear):
    """The band is what tyres can do: the most under- and the most oversteering pair of the
    plausible range, driven at the speed the slow holds allow, turn within it (and are not
    called a calibration error), yet visibly away from 1."""
    lo, hi = PLAUSIBLE_PER_RAD
    k_max = held.NONLINEAR_ALLOWANCE * (1 / lo - 1 / hi) / held.G
    car = Car(c_front=c_front, c_rear=c_rear)
    v = 0.9 * np.sqrt(held.MAX_TYRE_SHARE * car.L / k_max)
    path, vehicle, _ = teleop_log(tmp_path, "ends", car=car, speed=v / 1.12, amplitude=0.12)
    gain = held.steering_gain(load_runs([path], vehicle), vehicle.L, PLAUSIBLE_PER_RAD)
    assert gain is not None
    assert gain.band[0] <= gain.gain <= gain.band[1], gain
    assert not gain.far_from_one(), gain
    assert abs(gain.gain - 1) > 0.05, gain  # the speed was high enough for the tyres to show


def clip_shares(steer, vx):
    """Each extreme's share of the moving samples within 0.5% of the column's span of it (the
    warning's "at": a sample is the held command's mean over its period, so the one where the
    command reaches the clip just after its start is 99.9% at it)."""
    moving = vx > 1.0
    top, bottom = steer[moving].max(), steer[moving].min()
    tol = 0.005 * (top - bottom)
    return float(np.mean(np.abs(steer[moving] - top) <= tol)), float(np.mean(np.abs(steer[moving] - bottom) <= tol))


def clip_warning(run):
    found = [w for w in run.meta.get("warnings", []) if w.startswith("steer sits at its")]
    return found[0] if found else None


def test_a_clipped_command_is_said_with_its_share_and_where_the_wheels_were(tmp_path):
    """The operator asks up to 0.4 rad, the command is clipped at 0.25 and the wheels follow
    the command: the warning gives each extreme's share of the moving time as the data hold it,
    and the car, held at the clip, turned ~1 of it."""
    clip = lambda d: np.clip(d, -0.25, 0.25)  # noqa: E731
    path, vehicle, steer = teleop_log(tmp_path, "clip", amplitude=0.4, logged=clip, wheels=clip)
    (run,) = load_runs([path], vehicle)
    text = clip_warning(run)
    assert text, run.meta.get("warnings")
    said = [float(x) for x in re.findall(r"for ([0-9]+)% of the moving time", text)]
    vx = pd.read_csv(path)["vx"].to_numpy()
    want = clip_shares(steer, vx)
    assert len(said) == 2 and want[0] > 0.1 and want[1] > 0.1, (said, want)
    for s, w in zip(said, want):
        assert s == pytest.approx(100 * w, abs=1.0), (said, want)
    m = re.search(r"the car turned ([0-9.]+) of it", text)
    assert m and float(m.group(1)) == pytest.approx(1.0, abs=0.08), text
    assert "about where the column says" in text


def test_a_clip_in_the_logging_that_the_wheels_went_beyond_is_told_apart(tmp_path):
    """An operator asking up to 0.5 rad, the wheels getting all of it and only the log stopping
    at 0.25: held at the clip, the car turned more than the column says, and more than it
    turned of the steer held inside the clip. (Asked up to 0.4 rad, the wheels' mean at the clip
    is 1.17 of it against 0.99 inside, which the scatter of 10 holds does not tell apart.)"""
    path, vehicle, _ = teleop_log(tmp_path, "logclip", amplitude=0.5, duration=90.0,
                                  logged=lambda d: np.clip(d, -0.25, 0.25))
    (run,) = load_runs([path], vehicle)
    text = clip_warning(run)
    assert text and "not where the column says" in text, text
    assert float(re.search(r"the car turned ([0-9.]+) of it", text).group(1)) > 1.1, text


@pytest.mark.parametrize("levels", [(0.0, 0.2, -0.2), (0.15,)])
def test_a_chosen_amplitude_is_not_a_clip(tmp_path, levels):
    """Step steer between 0 and +-0.2 rad, and one circle held the whole run: the steer sits
    at its extremes by design, with nothing in between."""
    path, vehicle, _ = teleop_log(tmp_path, "steps", levels=levels, duration=40.0)
    (run,) = load_runs([path], vehicle)
    assert clip_warning(run) is None, run.meta.get("warnings")


# -- the real log --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def real_vehicle():
    return load_vehicle(REAL / "vehicle.toml")


def test_the_real_cars_soft_tyres_are_said_and_its_steering_calibration_is_not_blamed(real_vehicle):
    """ds3: the bicycle fits Cf ~ 15 N/rad (0.7 /rad of the front axle's load). Held at its
    +-0.34 rad clip, the car turns as far as the command says (its curvature L r / vx against
    the steer, measured here from the CSV), so the line must not blame the steering gain."""
    df = pd.read_csv(REAL / "ds3.csv")
    runs = load_runs([REAL / "ds3.csv"], real_vehicle)
    res = fit(runs, real_vehicle, "bicycle", "time")
    line = stiffness_line(res)
    assert line is not None, res.warnings
    assert "no tyre is that soft" in line
    assert "[steering] gain" not in line and "does not point at the steering calibration" in line
    # the yardstick, from the CSV alone: at the clip, settled, moving, the turned angle over the steer
    held_half_a_second = df["steer"].rolling(int(0.5 * 23) + 1).apply(np.ptp, raw=True) == 0
    settled = np.isclose(df["steer"].abs(), 0.34) & (df["vx"] > 1.0) & held_half_a_second
    ratio = float(np.mean(real_vehicle.L * df["r"][settled] / df["vx"][settled] / df["steer"][settled]))
    said = float(re.search(r"the car turned ([0-9.]+) of the logged steer", line).group(1))
    assert said == pytest.approx(ratio, abs=0.05), (said, ratio)


def test_the_real_logs_clip_is_said_with_the_share_its_data_hold(real_vehicle):
    for name in ("ds1.csv", "ds3.csv", "ds4.csv"):
        df = pd.read_csv(REAL / name)
        (run,) = load_runs([REAL / name], real_vehicle)
        text = clip_warning(run)
        assert text, (name, run.meta.get("warnings"))
        said = [float(x) for x in re.findall(r"for ([0-9]+)% of the moving time", text)]
        want = clip_shares(df["steer"].to_numpy(), df["vx"].to_numpy())
        for s, w in zip(said, want):
            assert s == pytest.approx(100 * w, abs=1.0), (name, said, want)
