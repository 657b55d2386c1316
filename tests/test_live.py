"""stid live: the numbers stid fit gives on the file at that moment, what the data lack,
bad input said in words; the views (terminal, web page in a real browser); the logger
never loses a sample to it.

Data: a single-track car written here from its textbook equations (scipy's lsim, noise
of the sensors' size), the simulated car running the real firmware, and hand-framed
logger streams (no HELLO).
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import signal
import subprocess
import time
import urllib.request
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from conftest import tool

TRUTH = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}
MASS, A, B = 9.31, 0.2326, 0.2874
VEHICLE = f'name = "physics car"\nmass = {MASS}\na = {A}\nb = {B}\n'


def bicycle_csv(path: Path, seconds, speeds=(4.0,), seed: int = 0, fs: float = 500.0,
                steer_rms_deg: float = 2.0) -> None:
    """The linear single track from its equations, m (vy' + vx r) = Fyf + Fyr and
    Iz r' = a Fyf - b Fyr with Fyf = Cf (delta - (vy + a r)/vx), Fyr = -Cr (vy - b r)/vx,
    driven by 4 Hz band-limited random steer; ay = (Fyf + Fyr)/m. ``seconds`` at each of
    ``speeds`` in turn (one number: the same for each), the state carried across a change of
    speed; white noise of the ADXL335/LISY300AL's size on ay and r."""
    from scipy import signal as sg

    rng = np.random.default_rng(seed)
    cols = []
    t0 = 0.0
    state = np.zeros(2)
    sos = sg.butter(6, 4.0, fs=fs, output="sos")
    durations = [seconds] * len(speeds) if np.isscalar(seconds) else list(seconds)
    for vx, dur in zip(speeds, durations):
        n = int(dur * fs)
        steer = sg.sosfiltfilt(sos, rng.standard_normal(n + 2000))[1000:-1000]
        steer *= math.radians(steer_rms_deg) / steer.std()
        Cf, Cr, Iz = TRUTH["Cf"], TRUTH["Cr"], TRUTH["Iz"]
        Amat = np.array([[-(Cf + Cr) / (MASS * vx), (-A * Cf + B * Cr) / (MASS * vx) - vx],
                         [(-A * Cf + B * Cr) / (Iz * vx), -(A * A * Cf + B * B * Cr) / (Iz * vx)]])
        Bmat = np.array([[Cf / MASS], [A * Cf / Iz]])
        # outputs: ay = vy' + vx r, r
        C = np.array([Amat[0] + [0.0, vx], [0.0, 1.0]])
        D = np.array([[Bmat[0, 0]], [0.0]])
        t = np.arange(n) / fs
        _, y, x = sg.lsim((Amat, Bmat, C, D), steer, t, X0=state)
        state = x[-1]
        ay = y[:, 0] + 0.05 * rng.standard_normal(n)
        r = y[:, 1] + 0.005 * rng.standard_normal(n)
        cols.append(np.column_stack([t0 + t, steer, ay, r, np.full(n, vx)]))
        t0 += n / fs
    data = np.vstack(cols)
    np.savetxt(path, data, delimiter=",", header="t,steer,ay,r,vx", comments="", fmt="%.8g")


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    d = tmp_path_factory.mktemp("live")
    (d / "car.toml").write_text(VEHICLE)
    return d


def _vehicle(car_dir):
    from stid.vehicle_file import load_vehicle

    return load_vehicle(car_dir / "car.toml")


def _stid_fit_json(run: Path, vehicle: Path, model: str = "bicycle") -> dict:
    """``stid fit RUN --method time --json``, the command's own function (a cold fit, with its
    multistart; in this process only to spare the suite an interpreter start per call)."""
    from contextlib import redirect_stdout

    from stid.cli import main

    out = io.StringIO()
    with redirect_stdout(out):
        rc = main(["fit", str(run), "--vehicle", str(vehicle), "--model", model, "--method", "time", "--json"])
    assert rc == 0
    return json.loads(out.getvalue())


# -- the numbers are stid fit's ---------------------------------------------------------

def test_each_update_gives_what_stid_fit_gives_on_the_file_at_that_moment(car, tmp_path):
    """A CSV growing row by row (as a logger appends), the estimator warm-started from one
    update to the next; at every update stid fit (a fresh process, cold start, multistart)
    on a copy of the file as it was then. Same optimum: the values differ by a small part
    of the interval, and the intervals by a few percent."""
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    full = tmp_path / "full.csv"
    bicycle_csv(full, 40.0, seed=3)
    rows = full.read_text().splitlines(keepends=True)
    growing = tmp_path / "growing.csv"
    est = Estimator(_vehicle(car), "bicycle", {"Iz": 1.0}, "test")
    compared = 0
    for frac in (0.4, 0.7, 1.0):
        growing.write_text("".join(rows[:1 + int(frac * (len(rows) - 1))]))
        up = est.update(Source(growing, _vehicle(car)).poll(), growing.name)
        assert up.params, up.state
        moment = tmp_path / f"moment_{frac}.csv"
        shutil.copy(growing, moment)
        ref = _stid_fit_json(moment, car / "car.toml")["params"]
        for p in up.params:
            lo, hi = ref[p.name]["ci95"]
            half = 0.5 * (hi - lo)
            assert abs(p.value - ref[p.name]["value"]) <= 0.05 * half, (frac, p, ref[p.name])
            assert abs(p.half95 / half - 1.0) <= 0.05, (frac, p, ref[p.name])
            # and the physics: the interval holds the car's value
            assert abs(p.value - TRUTH[p.name]) <= p.half95 * 1.05, (frac, p)
        compared += 1
    assert compared == 3 and len(est.history) == 3


def test_a_growing_stid_log_read_up_to_its_last_chunk_matches_stid_fit(simdir, tmp_path):
    """What a reader sees of a file stid-log is writing is a byte prefix of it (flushed
    chunks, then a chunk cut anywhere): the live update on such a prefix is stid fit's on
    the same bytes. (The simulated car with a servo lag, its real firmware, the session's run.)"""
    from simdata import random_steer_pair

    from stid.live.estimator import Estimator
    from stid.live.source import Source
    from stid.vehicle_file import load_vehicle

    run = random_steer_pair(simdir, ("actuator_lag",))[0]
    veh_path = Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml"
    vehicle = load_vehicle(veh_path)
    data = run.read_bytes()
    est = Estimator(vehicle, "bicycle+actuator_lag", {}, "test")
    for frac in (0.5, 0.8):
        part = tmp_path / f"part_{frac}.mcap"
        part.write_bytes(data[:int(frac * len(data)) + 1234])  # cut inside a chunk
        up = est.update(Source(part, vehicle).poll(), part.name)
        assert up.params and not up.finished, up.state
        ref = _stid_fit_json(part, veh_path, "bicycle+actuator_lag")["params"]
        for p in up.params:
            lo, hi = ref[p.name]["ci95"]
            half = 0.5 * (hi - lo)
            assert abs(p.value - ref[p.name]["value"]) <= 0.05 * half, (frac, p, ref[p.name])
            assert abs(p.half95 / half - 1.0) <= 0.05, (frac, p, ref[p.name])
    # the servo lag is the car's (the simulator's 60 ms)
    tau = next(p for p in up.params if p.name == "tau_steer")
    assert abs(tau.value - 0.060) <= max(tau.half95, 0.002), tau


# -- what the data lack -----------------------------------------------------------------

def test_done_once_every_target_is_reached_and_not_before(car, tmp_path):
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    run = tmp_path / "run.csv"
    bicycle_csv(run, 30.0, seed=5)
    loose = Estimator(_vehicle(car), "bicycle", {"Cf": 20.0, "Cr": 20.0, "Iz": 20.0}, "test")
    up = loose.update(Source(run, _vehicle(car)).poll(), run.name)
    assert up.done and up.done.startswith("done:"), up
    tight = Estimator(_vehicle(car), "bicycle", {"Iz": 0.01}, "test")
    up = tight.update(Source(run, _vehicle(car)).poll(), run.name)
    assert up.done is None
    iz = next(p for p in up.params if p.name == "Iz")
    assert iz.met is False and iz.target == 0.01
    assert up.lacking, "a target not reached says what to drive"


def test_no_done_for_a_model_the_diagnosis_says_lacks_an_effect(car, tmp_path):
    """Targets reached by a model that misses what the car has are not the answer: its intervals
    hold only if it were right (the demo's bicycle reads Iz 0.84 +-9% where the car's is 0.25)."""
    from stid.live.estimator import Estimator
    from stid.live.follow import with_named_effect
    from stid.live.source import Source

    run = tmp_path / "run.csv"
    bicycle_csv(run, 30.0, seed=5)
    up = Estimator(_vehicle(car), "bicycle", {"Cf": 20.0, "Cr": 20.0, "Iz": 20.0}, "test").update(
        Source(run, _vehicle(car)).poll(), run.name)
    assert up.done
    with_named_effect(up, "bicycle", "actuator_lag")
    assert up.done is None
    assert any("--model bicycle+actuator_lag" in x and "reached target is not the answer" in x for x in up.lacking), up.lacking
    with_named_effect(up, "bicycle", "actuator_lag")  # said once, however often the view updates
    assert sum("actuator_lag" in x for x in up.lacking) == 1
    assert "actuator_lag" in up.lacking[0]  # first: more driving with this model does not help


def test_a_model_the_diagnosis_rejects_gets_no_driving_plan(car, tmp_path):
    """The plan's "drive N min more for Iz" is worked out as if the watched model were right;
    on a model the diagnosis rejects it swung from update to update (a trial: bicycle on a
    lagged car, Cf +-10% then +-16% with more data). Once the diagnosis names an effect, or
    finds an error no effect explains, those lines go; a stand-still, lacking whatever the
    model, stays."""
    from stid.live import lacks
    from stid.live.estimator import Estimator
    from stid.live.follow import with_named_effect, with_unexplained_error
    from stid.live.source import Source

    run = tmp_path / "run.csv"
    bicycle_csv(run, 30.0, seed=5)
    est = Estimator(_vehicle(car), "bicycle", {"Iz": 0.01}, "test")
    up = est.update(Source(run, _vehicle(car)).poll(), run.name)
    assert up.lacking and up.done is None  # a plan for a target out of reach
    up.lacking = [lacks.STAND_STILL] + up.lacking
    with_named_effect(up, "bicycle", "actuator_lag")
    assert len(up.lacking) == 2 and "--model bicycle+actuator_lag" in up.lacking[0]
    assert up.lacking[1] == lacks.STAND_STILL
    up = est.update(Source(run, _vehicle(car)).poll(), run.name)
    with_unexplained_error(up, "bicycle")
    assert up.done is None and len(up.lacking) == 1 and "no catalogue effect explains" in up.lacking[0]


def test_the_diagnosis_verdict_says_an_error_no_effect_explains():
    """``named`` empty is "nothing missing" only when the model is at its noise floor; short
    of it (``unexplained.significant``) the catalogue lacks what the car has."""
    from stid.live.diagnosis import unexplained, verdict

    doc = {"model": "bicycle", "named": [], "candidates": [], "fit": {"ay": 80.2, "r": 91.0},
           "noise_floor": {"ay": 99.1, "r": 98.0},
           "unexplained": {"significant": True, "model": "bicycle", "gap": {"ay": 18.9, "r": 7.0}}}
    text = verdict(json.dumps(doc), 40.0)
    assert "misses something no effect of the catalogue explains" in text and "ay 80.2% where the noise allows 99.1%" in text
    assert "nothing missing" not in text and unexplained(json.dumps(doc))
    doc["unexplained"]["significant"] = False
    assert "nothing missing from bicycle" in verdict(json.dumps(doc), 40.0) and not unexplained(json.dumps(doc))
    # a candidate whose fit stopped short: what it explains is not known (stid.present says the same)
    doc["unexplained"]["significant"] = True
    doc["candidates"] = [{"effect": "steer_offset", "significant": False, "converged": False}]
    text = verdict(json.dumps(doc), 40.0)
    assert "the catalogue is not ruled out" in text and "bicycle+steer_offset did not converge" in text, text


def test_the_diagnosis_verdict_of_a_model_above_its_noise_floor_claims_nothing():
    """Tyres deep in saturation: bicycle+tyre_saturation fits ay 98.5% where the floor reads 94.7%
    +- 0.96. diagnose then names nothing more and says why; the live line said "nothing missing ...
    that these data show", which the data cannot say. (test_diagnose reads this line from a real
    diagnosis of such tyres.)"""
    from stid.live.diagnosis import verdict

    doc = {"model": "bicycle+tyre_saturation", "named": [], "candidates": [], "fit": {"ay": 98.5, "r": 99.0},
           "noise_floor": {"ay": 94.7, "r": 98.8}, "noise_floor_stderr": {"ay": 0.96, "r": 0.3},
           "above_floor": {"ay": 3.8}}
    text = verdict(json.dumps(doc), 40.0)
    assert "fits above the noise floor (ay)" in text and "nothing missing" not in text, text


def test_no_done_before_the_diagnosis_has_answered(car, tmp_path):
    """A trial run: 12 s of a car with a servo lag and an offset accelerometer, watched with
    bicycle+actuator_lag and loose targets, printed done with every interval off the truth while
    the diagnosis still waited for 15 s of driving."""
    from stid.live.estimator import Estimator
    from stid.live.follow import before_the_diagnosis
    from stid.live.source import Source

    run = tmp_path / "run.csv"
    bicycle_csv(run, 30.0, seed=5)
    up = Estimator(_vehicle(car), "bicycle", {"Cf": 20.0, "Cr": 20.0, "Iz": 20.0}, "test").update(
        Source(run, _vehicle(car)).poll(), run.name)
    assert up.done
    before_the_diagnosis(up)
    assert up.done is None and up.lacking[0].startswith("the diagnosis (once 15 s of driving")


class _NotAskedToDrive(Exception):
    """The view's last 'still lacking' line is not a driving addition (a model-error allowance)."""


def _asked(line: str):
    """(what, seconds, speed or None) from a 'still lacking' line."""
    import re

    m = re.search(r"about ([\d.]+) (s|min)", line)
    if m is None:
        raise _NotAskedToDrive(line)
    seconds = float(m.group(1)) * (60 if m.group(2) == "min" else 1)
    speed = re.search(r"about ([\d.]+) m/s", line)
    return line.split(":")[0].split(",")[0], seconds, float(speed.group(1)) if speed else None


def _halve_iz_and_drive_what_is_asked(car_dir, tmp_path, seed: int):
    """30 s at 4 m/s; Iz's target set to half its interval; the seconds of what the view asks
    for driven (the same physics, the state carried on); Iz's interval then / the target."""
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    first = tmp_path / f"first_{seed}.csv"
    bicycle_csv(first, 30.0, seed=seed)
    est = Estimator(_vehicle(car_dir), "bicycle", {}, "test")
    iz = next(p for p in est.update(Source(first, _vehicle(car_dir)).poll()).params if p.name == "Iz")
    est.targets = {"Iz": iz.percent / 2}
    up = est.update(Source(first, _vehicle(car_dir)).poll())
    what, seconds, speed = _asked(up.lacking[-1])
    assert what in ("a second speed", "more of the same"), up.lacking
    both = tmp_path / f"both_{seed}.csv"
    bicycle_csv(both, (30.0, seconds), speeds=(4.0, speed or 4.0), seed=seed)
    after = Estimator(_vehicle(car_dir), "bicycle", {}, "test").update(Source(both, _vehicle(car_dir)).poll())
    return next(p for p in after.params if p.name == "Iz").percent / (iz.percent / 2), up


def test_what_is_asked_for_says_how_long_and_more_of_the_same_adds_information_linearly(car, tmp_path):
    """One speed, an exact model: the view names an addition and its seconds. Its seconds
    come from information that adds: more of the same driving, to halve an interval (four
    times the information), takes three times the seconds fitted so far."""
    from stid.live import lacks
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    ratio, up = _halve_iz_and_drive_what_is_asked(car, tmp_path, seed=6)
    assert 0.3 < ratio < 3.0, ratio  # (one seed: the interval's own spread; the slow test measures it)
    run = tmp_path / "first_6.csv"
    est = Estimator(_vehicle(car), "bicycle", {}, "test")
    est.update(Source(run, _vehicle(car)).poll())
    res, runs = est.last_fit, Source(run, _vehicle(car)).poll().runs
    s = lacks.summary(runs, res)
    names = list(res.names)
    from stid.crlb import residual_model

    A0, B0 = lacks._driven_terms(runs, est.model, res.all_params(), names, residual_model(res.predictions), s)
    same = lacks._seconds_to_reach(A0, B0, A0 / s["seconds"], B0 / s["seconds"], [names.index("Iz")], [0.25])
    assert same == pytest.approx(3 * s["seconds"], rel=0.03), (same, s["seconds"])


@pytest.mark.slow
def test_driving_what_is_asked_for_reaches_the_target(car, tmp_path):
    """Over 12 seeds: after driving what the view asked for (its addition, its seconds), Iz's
    printed interval is the target, in the median, to within 0.7-1.4x (measured on these
    seeds: 0.88, each 0.65-1.23; a single run's interval spreads so around it: it is the
    wider of two estimates, one the block jackknife's with 7 degrees of freedom)."""
    ratios, held = [], []
    for seed in range(40, 52):
        try:
            ratios.append(_halve_iz_and_drive_what_is_asked(car, tmp_path, seed)[0])
        except _NotAskedToDrive as e:
            held.append((seed, str(e)))
    print("interval after / target:", np.round(ratios, 2), "median", np.median(ratios), "not asked:", held)
    assert 0.7 <= float(np.median(ratios)) <= 1.4, ratios
    # Seed 49 is not asked to drive: its exact model's fit shows a delay of -0.069 ms +- 0.027 (z -2.6,
    # chance: the delay allowance widens from 2 standard errors, so about one exact fit in 20), Iz's
    # interval is widened to 1.13% (0.3% without), and the view says the interval holds a delay. Found
    # failing so on 2026-11-27 (at 59c58be too); more than one such seed of 12 is more than chance.
    assert len(held) <= 1, held


def test_a_second_speed_is_what_separates_servo_lag_from_tyre_relaxation(tmp_path):
    """At one speed a servo lag tau and a relaxation lag sigma/vx look alike (the plan
    warns: 0.9+ correlated); only a second speed tells them apart. On one-speed data the
    view asks for a second speed for them, not for more of the same."""
    from stid.live.estimator import Estimator
    from stid.live.source import Source
    from stid.vehicle_file import load_vehicle

    run = tmp_path / "one_speed.mcap"
    r = subprocess.run([tool("stid-sim"), "--fast", "-o", str(run), "--duration", "25", "--seed", "7",
                        "--speed", "4", "--effects", "actuator_lag,tyre_relaxation"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    vehicle = load_vehicle(Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml")
    est = Estimator(vehicle, "bicycle+actuator_lag+tyre_relaxation", {}, "test")
    now = {p.name: p.percent for p in est.update(Source(run, vehicle).poll(), run.name).params}
    est.targets = {"tau_steer": now["tau_steer"] / 2, "sigma_f": now["sigma_f"] / 2}  # 4x the information
    up = est.update(Source(run, vehicle).poll(), run.name)
    assert up.params, up.state
    assert any(line.startswith("a second speed") and "now 4.0 m/s only" in line for line in up.lacking), up.lacking


def test_no_stand_still_asks_for_one_and_stand_still_only_asks_to_drive(tmp_path):
    from stid.live.estimator import Estimator
    from stid.live.source import Source
    from stid.vehicle_file import load_vehicle

    vehicle = load_vehicle(Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml")
    rolling = tmp_path / "rolling.mcap"
    still = tmp_path / "still.mcap"
    for path, args in ((rolling, ["--still", "0", "--duration", "12"]),
                       (still, ["--manoeuvre", "standstill", "--duration", "6"])):
        r = subprocess.run([tool("stid-sim"), "--fast", "-o", str(path), *args], capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stderr
    up = Estimator(vehicle, "bicycle", {}, "t").update(Source(rolling, vehicle).poll(), "rolling")
    assert any("stand still 3 s for the gyro zero" in s for s in up.lacking), up.lacking
    up = Estimator(vehicle, "bicycle", {}, "t").update(Source(still, vehicle).poll(), "still")
    assert not up.params
    assert any("only stood still" in s for s in up.state), up.state
    assert any(s.startswith("drive:") for s in up.lacking), up.lacking


# -- bad input, said in words ------------------------------------------------------------

def test_no_hello_yet_a_missing_file_an_empty_one_and_a_quiet_port_are_said(tmp_path, monkeypatch):
    from test_files_damage import circle_stream, record

    from stid.live import source as source_mod
    from stid.live.estimator import Estimator
    from stid.live.source import Source
    from stid.vehicle_file import default_vehicle

    vehicle = default_vehicle()
    est = Estimator(vehicle, "bicycle", {}, "t")
    missing = Source(tmp_path / "not_yet.mcap", vehicle)
    assert "waiting for" in est.update(missing.poll()).state[0]
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert "empty so far" in est.update(Source(empty, vehicle).poll()).state[0]
    bare = tmp_path / "bare.mcap"
    record(circle_stream(6.0, hello_every_s=None), bare)
    up = est.update(Source(bare, vehicle).poll())
    assert any(s.startswith("no HELLO from the board yet") for s in up.state), up.state
    assert not up.params
    # the port goes quiet: no new sample for QUIET_S, the view says so and goes on
    monkeypatch.setattr(source_mod, "QUIET_S", 0.3)
    half = tmp_path / "half.mcap"
    record(circle_stream(6.0), half, flush_s=1.0)
    data = half.read_bytes()
    half.write_bytes(data[:len(data) // 2])
    src = Source(half, vehicle)
    assert not any("gone quiet" in s for s in src.poll().state)
    time.sleep(0.4)
    snap = src.poll()
    assert any("no new samples since" in s and "gone quiet" in s for s in snap.state), snap.state
    assert snap.samples > 0  # what it had is kept
    time.sleep(1.1)  # (a piped view printed its whole block again whenever the line changed: every 2 s)
    assert src.poll().state == snap.state


def test_targets_from_the_command_line_the_vehicle_file_or_the_default(tmp_path):
    from stid.errors import InputError
    from stid.live.targets import DEFAULT_PERCENT, choose, parse_cli
    from stid.models.model import Model
    from stid.vehicle_file import load_vehicle

    (tmp_path / "v.toml").write_text(VEHICLE + '\n[targets]\nIz = "3%"\ntau_steer = 4\n')
    v = load_vehicle(tmp_path / "v.toml")
    assert v.targets == {"Iz": 3.0, "tau_steer": 4.0}
    m = Model("bicycle+actuator_lag", v)
    assert choose(m, parse_cli(["Cf=2%"]), v.targets) == ({"Cf": 2.0}, "--target")
    assert choose(m, {}, v.targets)[0] == {"Iz": 3.0, "tau_steer": 4.0}
    plain = Model("bicycle+steer_offset", load_vehicle(car_file(tmp_path)))
    got, where = choose(plain, {}, {})
    assert got == {"Cf": DEFAULT_PERCENT, "Cr": DEFAULT_PERCENT, "Iz": DEFAULT_PERCENT} and "default" in where
    for bad, words in (("Iz=0%", "above 0"), ("Iz", "NAME=PERCENT"), ("Iz=abc", "a percent"), ("Qz=3", "no parameter Qz")):
        with pytest.raises(InputError, match=words):
            choose(m, parse_cli([bad]), {})
    (tmp_path / "w.toml").write_text(VEHICLE + '\n[targets]\nIzz = "3%"\n')
    with pytest.raises(InputError, match="did you mean 'Iz'"):
        load_vehicle(tmp_path / "w.toml")


def car_file(d: Path) -> Path:
    p = d / "plain.toml"
    p.write_text(VEHICLE)
    return p


def test_user_errors_end_in_one_line_and_a_non_zero_exit(tmp_path):
    car = car_file(tmp_path)
    cases = [
        ([tool("stid"), "live", "x.mcap", "--vehicle", str(tmp_path / "nope.toml")], "does not exist"),
        ([tool("stid"), "live", "x.mcap", "--vehicle", str(car), "--target", "Iz=200%"], "below 100"),
        ([tool("stid"), "live", "x.mcap", "--vehicle", str(car), "--model", "bicycle+warp"], "warp"),
        ([tool("stid"), "live", "x.mcap", "--vehicle", str(car), "--every", "0"], "above 0"),
        ([tool("stid"), "live", str(tmp_path / "x.mcap"), "--vehicle", str(car)], "add --follow"),
        ([tool("stid-log"), "/dev/null", "--live"], "--vehicle"),
        ([tool("stid-log"), "/dev/null", "--target", "Iz=3%"], "add --live"),
        ([tool("stid-log"), "/dev/null", "--live", "--vehicle", str(car), "--target", "Q=1"], "no parameter Q"),
        # a port beyond 65535 ended in Python's OverflowError; one in use named no port
        ([tool("stid"), "live", "x.mcap", "--vehicle", str(car), "--web", "99999"], "is not a port"),
        ([tool("stid-log"), "/dev/null", "--live", "--vehicle", str(car), "--web", "-5"], "is not a port"),
    ]
    import socket

    held = socket.socket()
    held.bind(("127.0.0.1", 0))
    held.listen()
    run = tmp_path / "run.csv"
    bicycle_csv(run, 5.0)
    cases.append(([tool("stid"), "live", str(run), "--vehicle", str(car), "--no-diagnose", "--web",
                   str(held.getsockname()[1])], f"--web {held.getsockname()[1]}: cannot serve"))
    for cmd, words in cases:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and "Traceback" not in r.stderr, (cmd, r.stderr)
        errors = [line for line in r.stderr.splitlines() if "error" in line]
        assert len(errors) == 1 and words in errors[0], (cmd, r.stderr)


# -- the views -------------------------------------------------------------------------

def _update(**kw):
    from stid.live.estimator import ParamState, Update

    up = Update(seq=kw.get("seq", 1), path="run.mcap", model="bicycle", seconds=kw.get("seconds", 12.0),
                driving_s=10.0, targets_from="--target")
    up.params = [ParamState("Iz", "kg m^2", 0.25, 0.01, 3.0)]
    up.fit = {"ay": 95.0, "r": 97.0}
    up.lacking = ["a second speed, about 6.0 m/s (now 4.0 m/s only): about 40 s of it for Iz"]
    return up


def test_terminal_redraws_in_place_and_keeps_messages_above_and_piped_is_plain_lines():
    from stid.live.terminal import TerminalView

    out = io.StringIO()
    tv = TerminalView(out, tty=True)
    tv.show(_update())
    n = out.getvalue().count("\n")
    tv.message("stid-log: warning: the port went away")
    tv.show(_update(seq=2, seconds=14.0))
    text = out.getvalue()
    assert f"\x1b[{n}F\x1b[J" in text  # back over the table, cleared, redrawn
    after = text.rsplit("the port went away", 1)[1]
    assert "update 2" in after and "\x1b[" in after  # the message stays; the table comes back below it
    assert "±4.0%" in text and "not yet" in text
    narrow = io.StringIO()  # a long line is wrapped, never cut: its end still reaches the driver
    up = _update()
    up.done = "done: every target of bicycle is reached after 60 s of data (Iz ±2.9% (≤ 3%)); the run is enough"
    with mock.patch("shutil.get_terminal_size", return_value=os.terminal_size((40, 24))):
        TerminalView(narrow, tty=True).show(up)
    shown = narrow.getvalue().splitlines()
    assert all(len(line) < 40 for line in shown) and "the run is enough" in " ".join(x.strip() for x in shown)
    piped = io.StringIO()
    tv = TerminalView(piped, tty=False)
    tv.show(_update())
    assert "\x1b" not in piped.getvalue()
    tv.message("stid-log: warning: the port went away")  # stamped as the updates: seconds of data, not a clock
    assert all(line.startswith("[  12.0 s]") for line in piped.getvalue().splitlines())


def test_the_web_server_streams_updates_and_serves_the_page_only_on_loopback():
    from stid.live.web import LiveServer

    srv = LiveServer(0)
    try:
        assert srv.url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(srv.url, timeout=5).read().decode()
        assert "EventSource" in page and "http" not in page.split("<script>", 1)[1].replace("/ack", "")
        srv.publish(_update().to_json())
        with urllib.request.urlopen(srv.url + "events", timeout=5) as ev:
            first = _sse(ev)
            srv.publish(_update(seq=2, seconds=20.0).to_json())
            second = _sse(ev)
        assert first["seq"] == 1 and second["seq"] == 2 and second["seconds"] == 20.0
        assert json.loads(urllib.request.urlopen(srv.url + "state", timeout=5).read())["seq"] == 2
    finally:
        srv.close()


def test_a_closed_page_leaves_the_viewers_list():
    """/viewers lists what each open page drew; a page closed (its event stream gone) was
    listed for ever. It is forgotten at the next update it can no longer receive."""
    from stid.live.web import LiveServer

    srv = LiveServer(0)

    def viewers():
        return json.loads(urllib.request.urlopen(srv.url + "viewers", timeout=5).read())

    def ack(view, seq):
        urllib.request.urlopen(urllib.request.Request(srv.url + "ack", data=json.dumps(
            {"view": view, "seq": seq}).encode(), headers={"Content-Type": "application/json"}), timeout=5)

    try:
        srv.publish(_update().to_json())
        kept = urllib.request.urlopen(srv.url + "events?view=kept", timeout=5)
        with urllib.request.urlopen(srv.url + "events?view=closed", timeout=5) as ev:
            _sse(ev)
            ack("closed", 1)
        _sse(kept)
        ack("kept", 1)
        assert set(viewers()) == {"kept", "closed"}
        deadline = time.monotonic() + 10
        seq = 1
        while "closed" in viewers():  # the closed stream is found at the next write to it
            assert time.monotonic() < deadline, viewers()
            seq += 1
            srv.publish(_update(seq=seq).to_json())
            _sse(kept)
            time.sleep(0.05)
        assert set(viewers()) == {"kept"}
        kept.close()
    finally:
        srv.close()


def _sse(stream) -> dict:
    data = None
    while True:
        line = stream.readline().decode().rstrip("\n")
        if line.startswith("data: "):
            data = json.loads(line[6:])
        elif line == "" and data is not None:
            return data


def test_the_diagnosis_line_from_stid_diagnose_json_as_documented():
    """The contract of DESIGN.md and docs/diagnosis.md: ``named`` (one effect or a pair),
    each candidate's own ``params`` and ``units``; before ``named`` existed, the best
    significant candidate."""
    from stid.live.diagnosis import named_effect, verdict

    one = {"model": "bicycle", "named": ["actuator_lag"], "candidates": [
        {"effect": "actuator_lag", "significant": True, "params": {"tau_steer": 0.055}, "units": {"tau_steer": "s"}},
        {"effect": "sensor_delay", "significant": False, "params": {"delay_s": 0.05}, "units": {"delay_s": "s"}}]}
    assert verdict(json.dumps(one), 40.0) == "diagnosis: actuator_lag likely: tau_steer 55 ms (stid diagnose, " \
                                             "40 s of driving)"
    pair = {"model": "bicycle", "named": ["actuator_lag", "accel_offset"], "candidates": [
        {"effect": "actuator_lag", "significant": True, "params": {"tau_steer": 0.06}, "units": {"tau_steer": "s"}},
        {"effect": "accel_offset", "significant": True, "named_with": "actuator_lag",
         "params": {"x_acc": 0.08}, "units": {"x_acc": "m"}}]}
    assert "actuator_lag + accel_offset likely: tau_steer 60 ms, x_acc 8.0 cm" in verdict(json.dumps(pair), 30)
    assert named_effect(json.dumps(pair)) == "actuator_lag+accel_offset"
    none = {"model": "bicycle+actuator_lag", "named": [], "candidates": []}
    assert "nothing missing from bicycle+actuator_lag" in verdict(json.dumps(none), 30)
    old = {"model": "bicycle", "candidates": [{"effect": "body_roll", "significant": True, "params": {}}]}
    assert named_effect(json.dumps(old)) == "body_roll"
    assert verdict("stid diagnose: error: ...", 30) is None


def test_the_diagnosis_line_says_when_the_named_model_is_still_short_of_the_noise_floor():
    """The demo's 6 m/s run alone names a servo lag of 39 ms (the car's is 60: its accelerometer's
    offset, not yet found, bends it), and the named model stays 2-3 points short of the floor. The
    line said "actuator_lag likely: tau_steer 39 ms" and nothing else; within chance of the floor
    it says nothing more."""
    from stid.live.diagnosis import verdict

    doc = {"model": "bicycle", "named": ["actuator_lag"], "noise_floor_stderr": {"ay": 0.025, "r": 0.025},
           "candidates": [{"effect": "actuator_lag", "significant": True, "params": {"tau_steer": 0.0393},
                           "units": {"tau_steer": "s"}}],
           "unexplained": {"significant": False, "model": "bicycle+actuator_lag", "gap": {"ay": 2.35, "r": 3.21}}}
    text = verdict(json.dumps(doc), 23)
    assert text.startswith("diagnosis: actuator_lag likely: tau_steer 39 ms; with it still ay 2.4, r 3.2 points "
                           "short of the noise floor: something more is missing") and text.endswith("23 s of driving)")
    doc["unexplained"]["gap"] = {"ay": 0.3, "r": 0.05}  # within MIN_GAP: at the floor
    assert verdict(json.dumps(doc), 23) == "diagnosis: actuator_lag likely: tau_steer 39 ms (stid diagnose, 23 s of driving)"
    doc["unexplained"]["gap"], doc["noise_floor_stderr"] = {"ay": 0.9, "r": 0.0}, {"ay": 0.5, "r": 0.025}
    assert "short of" not in verdict(json.dumps(doc), 23)  # 0.9 points is within 2.6 se of a short run's floor


def test_a_growing_log_reread_with_its_chunks_remembered_reads_as_a_fresh_read(tmp_path):
    """stid live keeps what a log's chunks held between reads (they never change once
    written): each read of the growing file equals a fresh read of it, samples, messages and
    damage alike, including a prefix cut inside a chunk."""
    from test_files_damage import circle_stream, record

    from host.mcap_read import read_log

    full = tmp_path / "full.mcap"
    record(circle_stream(12.0), full, flush_s=1.0)
    data = full.read_bytes()
    growing = tmp_path / "growing.mcap"
    chunks: dict = {}
    for frac in (0.3, 0.31, 0.6, 0.9, 1.0):
        growing.write_bytes(data[:int(frac * len(data))])
        remembered, fresh = read_log(growing, chunks), read_log(growing)
        assert np.array_equal(remembered.samples, fresh.samples)
        assert remembered.events == fresh.events and remembered.hellos == fresh.hellos
        assert remembered.truncated == fresh.truncated and remembered.frames == fresh.frames
        assert [vars(d) for d in remembered.damage] == [vars(d) for d in fresh.damage]
    assert chunks and len(fresh.samples) > 0


def test_an_update_slower_than_the_data_skips_ahead_to_the_newest(car, tmp_path, monkeypatch):
    """The file grows in 12 steps while every update takes 0.4 s (asked for every 0.05 s):
    the view never works through the steps one by one; each update is on the newest data,
    and the last one on all of it."""
    import threading

    from stid.live import follow
    from stid.live.estimator import Estimator

    full = tmp_path / "full.csv"
    bicycle_csv(full, 24.0, seed=9)
    rows = full.read_text().splitlines(keepends=True)
    growing = tmp_path / "growing.csv"
    growing.write_text("".join(rows[:len(rows) // 4]))
    slow = Estimator.update

    def slow_update(self, snap, path=""):
        time.sleep(0.4)
        return slow(self, snap, path)

    monkeypatch.setattr(Estimator, "update", slow_update)

    done = {}

    def grow():
        for k in range(1, 13):
            time.sleep(0.1)
            n = len(rows) // 4 + (len(rows) - len(rows) // 4) * k // 12
            growing.write_text("".join(rows[:n]))
        done["at"] = time.time()

    writer = threading.Thread(target=grow)
    out = io.StringIO()
    writer.start()
    stopper = threading.Timer(4.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    stopper.start()
    try:
        follow.live(growing, _vehicle(car), "bicycle", {}, "test", follow=True, every=0.05, json_lines=True,
                    diagnose=False, stream=out)
    finally:
        stopper.cancel()
        writer.join()
    ups = [json.loads(line) for line in out.getvalue().splitlines()]
    fitted = [u["seconds"] for u in ups if u["params"]]
    assert fitted == sorted(fitted)
    # every update whose read came after the last growth (its Update is made 0.4 s after the
    # read) is on all the data: none works through a backlog of older states
    late = [u["seconds"] for u in ups if u["wall"] - 0.4 > done["at"] + 0.05]
    assert late and all(x == pytest.approx(24.0, abs=0.01) for x in late), (late, fitted)


def test_a_ros2_bag_being_recorded_is_read_up_to_its_last_chunk_and_ends_as_stid_fit(tmp_path):
    """``ros2 bag record`` (MCAP storage) writes BAG/BAG_0.mcap chunk by chunk, and the file's
    end and the bag's metadata.yaml only when it stops; until then no ROS reader opens it.
    The view reads its complete chunks as they come; on the finished bag its numbers are
    stid fit's. (The car: tests/ros_data.py, plain physics; chunks as libmcap writes them.)"""
    import ros_data as rd

    from stid.live.estimator import Estimator
    from stid.live.source import Source
    from stid.vehicle_file import load_vehicle

    drive = rd.drive(40.0, seed=2)
    written = rd.as_libmcap_writes(rd.ros2_mcap(rd.write_bag(drive, tmp_path / "bag")), tmp_path / "lib.mcap",
                                   chunk_size=64 * 1024)
    car = rd.vehicle_toml(tmp_path / "car.toml")
    vehicle = load_vehicle(car)
    data = written.read_bytes()
    rec = tmp_path / "rec"
    rec.mkdir()
    growing = rec / "rec_0.mcap"
    src = Source(rec, vehicle)
    est = Estimator(vehicle, "bicycle", {}, "test")
    seconds = []
    for frac in (0.5, 0.8):
        growing.write_bytes(data[:int(frac * len(data))])
        up = est.update(src.poll(), "rec")
        assert up.params and any("being recorded" in s for s in up.state), up.state
        seconds.append(up.seconds)
    assert seconds[1] > seconds[0] + 5
    growing.write_bytes(data)  # recording stopped: the file has its end (rosbag2 then writes metadata.yaml)
    up = est.update(src.poll(), "rec")
    ref = _stid_fit_json(growing, car)["params"]
    for p in up.params:
        lo, hi = ref[p.name]["ci95"]
        assert abs(p.value - ref[p.name]["value"]) <= 0.05 * 0.5 * (hi - lo), (p, ref[p.name])


def test_the_excitation_map_puts_the_steer_where_it_was_driven():
    """A 3 Hz sine steer at 4 m/s for 20 s, then a 1 Hz one at 6 m/s for 10 s: the map's
    power sits in the (4 m/s, 3 Hz) and (6 m/s, 1 Hz) cells, in proportion to the seconds and
    the sines' power (both 1 deg amplitude: twice the seconds, twice the power)."""
    from stid.live.excitation import WINDOW_S, speed_frequency_map
    from stid.run import Run

    fs = 200.0
    t = np.arange(int(30 * fs)) / fs
    slow = t < 20
    steer = np.radians(np.where(slow, np.sin(2 * np.pi * 3 * t), np.sin(2 * np.pi * 1 * t)))
    vx = np.where(slow, 4.0, 6.0)
    run = Run(name="sines", t=t, steer=steer, ay=np.zeros_like(t), r=np.zeros_like(t), vx=vx, meta={"fs": fs})
    m = speed_frequency_map([run])
    power = np.array(m["power"])
    speeds, freqs = np.array(m["speeds"]), np.array(m["freqs"])
    row4 = int(np.flatnonzero(speeds == 4.0)[0])
    row6 = int(np.flatnonzero(speeds == 6.0)[0])
    assert freqs[np.argmax(power[row4])] == pytest.approx(3.0, abs=0.5)
    assert freqs[np.argmax(power[row6])] == pytest.approx(1.0, abs=0.5)
    # (a window across the change of speed counts at its mean speed, in neither row)
    assert m["seconds"][row4] == pytest.approx(20.0, abs=WINDOW_S)
    assert m["seconds"][row6] == pytest.approx(10.0, abs=WINDOW_S)
    # a sine of amplitude A holds A^2/2 of power: the 4 m/s row holds twice the 6 m/s row's
    assert power[row4].sum() / power[row6].sum() == pytest.approx(2.0, rel=0.1)


def test_a_csv_being_appended_is_read_up_to_its_last_whole_row(car, tmp_path):
    """A logger appending rows leaves the last one half written at times: the view reads the
    complete rows (and says nothing is wrong), not a half row as a bad value."""
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    full = tmp_path / "full.csv"
    bicycle_csv(full, 12.0, seed=4)
    data = full.read_bytes()
    cut = data.rfind(b"\n", 0, len(data) // 2) + 20  # inside a row
    growing = tmp_path / "growing.csv"
    growing.write_bytes(data[:cut])
    up = Estimator(_vehicle(car), "bicycle", {}, "t").update(Source(growing, _vehicle(car)).poll(), "growing.csv")
    assert up.params and not up.state, up.state
    rows = data[:cut].count(b"\n") - 1  # the header's line is not a row
    assert up.seconds == pytest.approx(rows / 500.0, abs=2 / 500.0)


def test_a_single_update_says_done_only_after_its_diagnosis(simdir):
    """`stid live RUN` (one update, no --follow) on a run with a servo lag the watched model lacks
    said "done: every target is reached; the run is enough", with no diagnosis: the background
    diagnosis ran only while following. A single update now runs it to its end first; with the lag
    in the model, the same targets are done."""
    from simdata import random_steer_pair

    run = random_steer_pair(simdir, ("actuator_lag",))[0]
    rc8 = str(Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml")

    def once(model):
        r = subprocess.run([tool("stid"), "live", str(run), "--vehicle", rc8, "--model", model, "--target", "Iz=20%"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        return r.stdout

    wrong = once("bicycle")
    assert "done:" not in wrong and "actuator_lag" in wrong and "diagnosis:" in wrong, wrong
    assert "done:" in once("bicycle+actuator_lag")


def test_a_parameter_the_data_do_not_determine_is_told_to_drive_random_steer_not_to_steer_less():
    """A steady circle: Iz had no interval ("the data so far do not determine it"), and the view told
    the driver "Iz: the interval holds the large-angle geometry ...: steer less", from the geometry's
    allowance, which was all its interval had. It lacks excitation across frequencies."""
    from types import SimpleNamespace

    from stid.live.estimator import ParamState
    from stid.live.lacks import lacking

    res = SimpleNamespace(converged=True, names=["Cf", "Iz"], ci_allowance=np.array([1.0, 0.05]),
                          delay_allowance=None)
    params = [ParamState("Cf", "N/rad", 300.0, 3.0, 5.0), ParamState("Iz", "kg m^2", 0.1, None, 1.0)]
    said = lacking([], res, None, params)
    assert any(s.startswith("Iz: not determined by the data so far") and "random steer" in s for s in said), said
    assert not any("steer less" in s and "Iz" in s for s in said), said


def test_the_page_of_a_single_update_stays_until_ctrl_c(tmp_path, simdir):
    """`stid live FINISHED --follow --web PORT` made its one update and ended: the page it had just
    printed the address of refused every connection. It now stays, said so, until Ctrl-C."""
    import socket

    from simdata import random_steer_pair

    car = Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml"
    run = random_steer_pair(simdir)[0]  # (a logged file, finished)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    view = subprocess.Popen([tool("stid"), "live", str(run), "--vehicle", str(car), "--no-diagnose", "--follow",
                             "--web", str(port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline, state = time.monotonic() + 60, None
        while state is None and time.monotonic() < deadline and view.poll() is None:
            time.sleep(0.3)
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/state", timeout=2) as r:
                    state = json.loads(r.read())
            except OSError:
                pass
        time.sleep(1.0)
        assert view.poll() is None, view.communicate()  # still serving after its one update
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/state", timeout=2) as r:
            assert json.loads(r.read())["params"], "the page shows the update"
    finally:
        view.send_signal(signal.SIGINT)
        out, err = view.communicate(timeout=30)
    assert view.returncode == 0 and "Traceback" not in err, err
    assert "the page stays at" in out, out


def test_a_delay_that_holds_an_interval_is_said_with_how_often_chance_shows_it(car, tmp_path):
    """An exact model's run (plain physics, seed 49) whose fit sees the outputs 0.07 ms early at
    2.6 standard errors: the interval widens for it (from 2 standard errors: about one exact fit in
    20), and the view said "which more data do not shrink", where a delay that is chance fades as
    the data grow. It now gives the delay, its standard errors and how often chance shows one, and
    says more data do not shrink it only if it is real."""
    from stid.live.estimator import Estimator
    from stid.live.source import Source

    first = tmp_path / "exact_49.csv"
    bicycle_csv(first, 30.0, seed=49)
    est = Estimator(_vehicle(car), "bicycle", {}, "test")
    iz = next(p for p in est.update(Source(first, _vehicle(car)).poll()).params if p.name == "Iz")
    est.targets = {"Iz": iz.percent / 2}
    line = est.update(Source(first, _vehicle(car)).poll()).lacking[-1]
    assert line.startswith("Iz: the interval holds a delay"), line
    import re

    m = re.search(r"the outputs 0\.069 ms early at 2\.6 standard errors, which chance gives in about 1 fit of (\d+)", line)
    assert m and 80 <= int(m.group(1)) <= 130, line  # (two-sided, z 2.6: 1 in ~100)
    assert "if it is real, more data do not shrink it" in line, line


def test_a_delay_far_beyond_chance_is_said_so_without_an_infinite_count():
    """A servo's lag seen at 44 standard errors: chance never gives it (the count of fits was
    1 / 0, an OverflowError that ended the live view in the suite's browser test)."""
    from types import SimpleNamespace

    from stid.live.lacks import _delay_seen

    words, chance = _delay_seen(SimpleNamespace(extra={"delay_seen_ms": (16.0, 0.36)}))
    assert "the outputs 16 ms late at 44.4 standard errors, far beyond what chance gives" in words and not chance
    words, chance = _delay_seen(SimpleNamespace(extra={"delay_seen_ms": (-0.069, 0.0268)}))
    assert "early at 2.6 standard errors, which chance gives in about 1 fit of" in words and chance
    assert _delay_seen(SimpleNamespace(extra={})) == ("", True)


def test_a_live_logger_that_gets_no_data_ends_at_its_idle_timeout(tmp_path):
    """A port that sends nothing: the logger gave up at its idle timeout and left no file, while its
    live view redrew 'waiting for ... to appear' for 20 s more, and only then came the logger's error."""
    master, slave = os.openpty()
    try:
        t0 = time.monotonic()
        r = subprocess.run([tool("stid-log"), os.ttyname(slave), "-o", str(tmp_path / "x.mcap"), "--idle-timeout", "2",
                            "--live", "--vehicle", str(car_file(tmp_path))], capture_output=True, text=True, timeout=60)
        took = time.monotonic() - t0
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode == 3 and "no data from" in r.stderr, r.stderr
    assert took < 12, took  # (the idle timeout, the view's start and one poll; it was 20 s more)
    assert not (tmp_path / "x.mcap").exists()
