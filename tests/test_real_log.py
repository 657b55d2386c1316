"""A real 1:10 car in the suite: FrictionMaps dataset 1 (tests/fixtures/real/frictionmaps_ds1,
MIT), a teleoperated F1/10 car, 43 s at 30 Hz, 1-4.9 m/s.

No test here knows a "right" stiffness: nobody measured one. The log carries its own
checks instead, which stid never sees: the particle filter's heading from the lidar
(``psi_pf``, independent of the IMU) and the car standing still at the end. What a command
prints is judged against those and against the data's own numbers (speeds, durations),
never against a tuned value.

Tests that fail today because other work on issue 21 is not merged yet are marked xfail
with the point they wait for; the lead turns them on after the merge.
"""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import cumulative_trapezoid

from conftest import REPO, tool

FIXTURE = REPO / "tests" / "fixtures" / "real" / "frictionmaps_ds1"
RUN = FIXTURE / "ds1.csv"
VEHICLE = FIXTURE / "vehicle.toml"
MOVING = 1.0  # m/s: the speed below which stid leaves a sample out of the dynamic fit
CATALOGUE_EFFECTS = ("tyre_relaxation", "actuator_lag", "accel_offset", "body_roll", "tyre_saturation",
                     "sensor_bias", "steering_nonlinearity", "locked_diff", "sensor_delay", "steer_offset",
                     "gyro_scale")

WAITS_FOR_SOLVER_HONESTY = ("issue 21 point 1 / 'Solvers that say when they fail': converged, status, at_bound "
                            "in --json and a line in the text; a contained model starts from its base")
WAITS_FOR_NULL_INTERVALS = ("issue 21 point 1 / 'Solvers that say when they fail': no zero-width interval, "
                            "null for a parameter the data do not determine")
WAITS_FOR_WORDS = "issue 21 point 5: every 'see below' has its section; no stray unit ('at 7.1 m/s s')"
WAITS_FOR_PAIRS = "issue 21 point 3 / 'Pairs before the catalogue lacks it': pairs tried, and said which"


def data() -> pd.DataFrame:
    return pd.read_csv(RUN)


def run_tool(*args, timeout=600) -> subprocess.CompletedProcess:
    r = subprocess.run([tool("stid"), *map(str, args)], capture_output=True, text=True, timeout=timeout,
                       cwd=FIXTURE)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stderr
    return r


# -- what the log itself says (the yardsticks; stid never sees psi_pf) ------------------

def heading_drift(df):
    """Yaw-rate bias the particle filter's heading allows: the slope of (integral of r minus
    the heading change) over time, and how far that slope can be off (twice the largest
    wander of the difference about its line, spread over the run)."""
    t = df["t"].to_numpy()
    err = cumulative_trapezoid(df["r"], t, initial=0.0) - (df["psi_pf"] - df["psi_pf"].iloc[0]).to_numpy()
    slope, icpt = np.polyfit(t, err, 1)
    wander = np.max(np.abs(err - (slope * t + icpt)))
    return float(slope), float(2 * wander / (t[-1] - t[0]))


def gyro_scale_from_heading(df):
    """k in r_meas = (1 + k) r from the integrated gyro against the heading, and its
    tolerance (the heading's largest wander about the line, twice, over the angle turned)."""
    t = df["t"].to_numpy()
    turned = (df["psi_pf"] - df["psi_pf"].iloc[0]).to_numpy()
    integral = cumulative_trapezoid(df["r"], t, initial=0.0)
    gain, icpt = np.polyfit(turned, integral, 1)
    wander = np.max(np.abs(integral - (gain * turned + icpt)))
    return float(gain - 1.0), float(2 * wander / np.ptp(turned))


def standing(df):
    return df[np.abs(df["vx"]) < 0.01]


def lateral_offset_range(df):
    """Where an accelerometer offset in ay can lie: between its value at rest and the mean
    of ay - vx*r while moving (r from the heading, which no gyro error reaches), widened by
    the +-10% a wheel-speed vx can be off (slip, tyre radius)."""
    dt = float(np.median(np.diff(df["t"])))
    r_true = np.gradient(df["psi_pf"].to_numpy(), dt)
    moving = df["vx"].to_numpy() > MOVING
    kin = float(np.mean((df["ay"] - df["vx"] * r_true)[moving]))
    rest = float(standing(df)["ay"].mean())
    slack = 0.1 * float(np.mean(np.abs(df["vx"] * r_true)[moving]))
    return min(kin, rest) - slack, max(kin, rest) + slack


# -- the fixture: made by the kept converter, and physically right -------------------------

def test_the_converter_reproduces_the_fixture_from_the_original_files(tmp_path):
    import sys

    out = tmp_path / "ds1.csv"
    r = subprocess.run([sys.executable, str(REPO / "tools" / "real_logs" / "convert_frictionmaps.py"),
                        str(FIXTURE / "original"), str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == RUN.read_bytes()


def test_the_converted_log_agrees_with_physics_it_was_not_fitted_to():
    """Units, axes and signs of the conversion, each checked against something independent:
    the lidar heading for r, the kinematics ay ~ vx*r for ay, gravity for the accelerometer."""
    df = data()
    k, tol = gyro_scale_from_heading(df)
    assert abs(k) < 0.05 + tol, (k, tol)  # deg/s -> rad/s and the sign (z up) are right
    slope, _ = heading_drift(df)
    assert abs(slope) < 0.02, slope  # < 1 deg/s of drift: no unit or axis mix-up in r
    moving = df["vx"] > MOVING
    # the slow part of ay follows vx*r with gain ~1 (ISO: both left positive, ay in m/s^2 not g)
    lp = lambda x: pd.Series(x).rolling(15, center=True, min_periods=1).mean().to_numpy()
    x, y = lp(df["vx"] * df["r"])[moving], lp(df["ay"])[moving]
    gain = float(np.dot(x - x.mean(), y - y.mean()) / np.dot(x - x.mean(), x - x.mean()))
    assert 0.8 < gain < 1.25, gain
    # at rest the horizontal axes see only a tilt's share of gravity: the vertical axis took it
    rest = standing(df)
    assert len(rest) >= 20
    assert np.hypot(rest["ay"].mean(), rest["ax"].mean()) < 0.15 * 9.81


# -- the commands: shared results ----------------------------------------------------------

@pytest.fixture(scope="module")
def runs_and_vehicle():
    from stid.load import load_runs
    from stid.vehicle_file import load_vehicle

    vehicle = load_vehicle(VEHICLE)
    return load_runs([RUN], vehicle), vehicle


@pytest.fixture(scope="module")
def fits(runs_and_vehicle):
    from stid.fit.fitting import fit

    runs, vehicle = runs_and_vehicle
    return {m: fit(runs, vehicle, m, "time") for m in ("bicycle", "bicycle+tyre_saturation")}


@pytest.fixture(scope="module")
def diagnosis(runs_and_vehicle):
    """diagnose --peel as a function: its JSON (as the command builds it) and its text."""
    from stid.diagnose import diagnose
    from stid.present import diagnosis_text

    runs, vehicle = runs_and_vehicle
    rounds = diagnose(runs, vehicle, "bicycle", peel=True)
    doc = rounds[0].to_json()
    doc["steps"] = [d.to_json() for d in rounds]
    doc["unexplained"] = rounds[-1].unexplained.to_json()
    return doc, diagnosis_text(rounds, [RUN.name], VEHICLE.name, peel=True)


# -- the checks, one per way a result can mislead ------------------------------------------

def named_parameters(doc) -> dict:
    """Parameters of everything the diagnosis tells the user to add: the models of the peel's
    rounds and the candidates it calls significant."""
    named = {}
    for step in doc.get("steps", [doc]):
        named.update({n: p["value"] for n, p in step["params"].items()})
        for c in step["candidates"]:
            if c.get("significant"):
                named.update(c.get("params", {}))
    return named


def named_effects(doc) -> set:
    final = doc["unexplained"]["model"].split("+")[1:]
    last = doc.get("steps", [doc])[-1]
    return set(final) | {c["effect"] for c in last["candidates"] if c.get("significant")}


def check_nothing_named_that_the_kinematics_rule_out(doc):
    df = data()
    params = named_parameters(doc)
    if "bias_r" in params:
        drift, tol = heading_drift(df)
        assert abs(params["bias_r"] - drift) <= tol, (
            f"bias_r {params['bias_r']:.4f} rad/s named, but the lidar heading allows {drift:.4f} +- {tol:.4f}")
    if "bias_ay" in params:
        lo, hi = lateral_offset_range(df)
        assert lo <= params["bias_ay"] <= hi, (params["bias_ay"], lo, hi)
    if "k_gyro" in params:
        k, tol = gyro_scale_from_heading(df)
        assert abs(params["k_gyro"] - k) <= tol, (params["k_gyro"], k, tol)


def check_speed_words(text):
    """Speeds the text names lie where the car drove; 'one speed' only for a run that held one."""
    moving = data()["vx"][data()["vx"] > MOVING]
    for said in re.findall(r"\bat ((?:\d+(?:\.\d+)?, )*\d+(?:\.\d+)?) m/s", text):
        for v in map(float, said.split(", ")):
            assert moving.min() - 0.1 <= v <= moving.max() + 0.1, (v, said)
    lo, hi = np.percentile(moving, [5, 95])
    if hi > 1.5 * lo:  # this run spans 1-4.9 m/s
        assert "one speed" not in text, text


def check_no_stray_unit(text):
    stray = re.findall(r"(?:m/s|deg rms|deg|rad|Hz) s\b", text)
    assert not stray, stray


def check_every_see_below_has_its_section(text):
    for name in re.findall(r"see '([^']+)' below", text):
        tail = text.split(f"see '{name}' below", 1)[1]
        assert re.search(rf"^\s*{re.escape(name)}\b", tail, re.M | re.I), f"'see {name} below' with no such section"


def check_catalogue_blamed_only_after_pairs(text):
    if "no effect of the catalogue" in text or "catalogue lacks" in text:
        pair = re.compile(r"\b(%s)\+(%s)\b" % ("|".join(CATALOGUE_EFFECTS), "|".join(CATALOGUE_EFFECTS)))
        assert pair.search(text), "blames the catalogue without saying which pairs were tried"


def test_the_checks_catch_what_the_review_saw():
    """The yardsticks are not loose enough to pass anything: what the review of issue 21 saw
    on a real log (a gyro offset of -0.198 rad/s, 'the runs hold one speed' for a run of
    1.2-4.4 m/s, 'at 7.1 m/s s', a 'see below' with nothing below) fails them here, and
    what this log's own heading and stand-still say passes."""
    drift, _ = heading_drift(data())
    rest_r = float(standing(data())["r"].mean())
    for ok in (drift, rest_r):
        check_nothing_named_that_the_kinematics_rule_out(
            {"steps": [{"params": {"bias_r": {"value": ok}}, "candidates": []}]})
    with pytest.raises(AssertionError, match="lidar heading allows"):
        check_nothing_named_that_the_kinematics_rule_out(
            {"steps": [{"params": {"bias_r": {"value": -0.198}}, "candidates": []}]})
    with pytest.raises(AssertionError):
        check_nothing_named_that_the_kinematics_rule_out(
            {"steps": [{"params": {}, "candidates": [{"significant": True, "params": {"k_gyro": 0.1}}]}]})
    with pytest.raises(AssertionError):
        check_speed_words("the runs hold one speed")
    with pytest.raises(AssertionError):
        check_speed_words("[2 stretches at 2.3, 7.1 m/s]")  # never driven at 7.1 m/s
    with pytest.raises(AssertionError):
        check_no_stray_unit("tau 32 ms at 3 m/s, 43 ms at 7.1 m/s s")
    with pytest.raises(AssertionError):
        check_every_see_below_has_its_section("=> nothing explains it (see 'unexplained' below)\n\nnext: stid fit")
    check_every_see_below_has_its_section("=> nothing explains it (see 'unexplained' below)\n\nunexplained: ay ...")


# -- fit (default suite) ---------------------------------------------------------------------

def test_stid_fit_as_a_command_gives_finite_numbers_and_true_notes(fits):
    df = data()
    doc = json.loads(run_tool("fit", RUN.name, "--vehicle", VEHICLE.name, "--json").stdout)  # only JSON on stdout
    assert doc["model"] == "bicycle"
    for name, p in doc["params"].items():
        assert np.isfinite(p["value"]) and p["value"] > 0, (name, p)
    # the command and the function give one answer
    for o in ("ay", "r"):
        assert doc["fit"][o] == pytest.approx(fits["bicycle"].fit[o], abs=0.01)
    # it says how long the car was too slow to fit, and that is what the data hold
    said = [re.search(r"([0-9.]+) s standing still or slower than 1 m/s", n) for n in doc["notes"]]
    said = [float(m.group(1)) for m in said if m]
    assert said, doc["notes"]
    slow = float(np.sum(np.diff(df["t"])[(df["vx"] < MOVING).to_numpy()[:-1]]))
    assert abs(said[0] - slow) <= 0.1 + 2 * float(np.median(np.diff(df["t"]))), (said, slow)


@pytest.mark.xfail(strict=False, reason=WAITS_FOR_SOLVER_HONESTY)
def test_the_fit_says_whether_it_converged(fits):
    for model, res in fits.items():
        doc = res.to_json()
        assert isinstance(doc.get("converged"), bool) and doc.get("status"), (model, sorted(doc))
        assert all("at_bound" in p for p in doc["params"].values()), model
        assert re.search(r"converged|did not converge|failed", res.table()), model


@pytest.mark.xfail(strict=False, reason=WAITS_FOR_SOLVER_HONESTY)
def test_a_model_with_more_never_fits_worse_without_saying_it_failed(fits):
    """bicycle+tyre_saturation contains bicycle (mu large): on this log its fit stopped at its
    start (ay 3.9% against the bicycle's 33.0%, mu 1 with a zero-width interval)."""
    base, more = fits["bicycle"], fits["bicycle+tyre_saturation"]
    worse = [o for o in ("ay", "r") if more.fit[o] < base.fit[o] - 0.5]
    if worse:
        doc = more.to_json()
        assert doc.get("converged") is False, (worse, more.fit, base.fit)
        assert re.search(r"did not converge|failed", more.table()), more.table()


@pytest.mark.xfail(strict=False, reason=WAITS_FOR_NULL_INTERVALS)
def test_no_interval_is_zero_wide(fits):
    for model, res in fits.items():
        for name, p in res.to_json()["params"].items():
            ci = p.get("ci95")
            if ci is not None:
                assert ci[1] - ci[0] > 1e-6 * max(1.0, abs(p["value"])), (model, name, ci)


# -- diagnose --peel as a function (default suite) -------------------------------------------

def test_diagnosis_names_nothing_the_kinematics_rule_out(diagnosis):
    doc, text = diagnosis
    check_nothing_named_that_the_kinematics_rule_out(doc)
    check_speed_words(text)
    # what it names is in the catalogue, and the verdict it prints is the one in its JSON
    assert named_effects(doc) <= set(CATALOGUE_EFFECTS), named_effects(doc)
    for effect in named_effects(doc):
        assert effect in text, effect


@pytest.mark.xfail(strict=False, reason=WAITS_FOR_WORDS)
def test_diagnosis_words_point_to_what_is_there(diagnosis):
    _, text = diagnosis
    check_every_see_below_has_its_section(text)
    check_no_stray_unit(text)


@pytest.mark.xfail(strict=False, reason=WAITS_FOR_PAIRS)
def test_the_catalogue_is_blamed_only_after_pairs_were_tried(diagnosis):
    _, text = diagnosis
    check_catalogue_blamed_only_after_pairs(text)


# -- the whole commands (slow: each runs the diagnosis again) --------------------------------

@pytest.mark.slow
def test_stid_diagnose_peel_as_a_command_is_honest():
    doc = json.loads(run_tool("diagnose", RUN.name, "--vehicle", VEHICLE.name, "--peel", "--json").stdout)
    check_nothing_named_that_the_kinematics_rule_out(doc)
    text = run_tool("diagnose", RUN.name, "--vehicle", VEHICLE.name, "--peel").stdout
    check_speed_words(text)
    for effect in named_effects(doc):
        assert effect in text, effect


@pytest.mark.slow
def test_stid_compare_as_a_command_is_honest():
    models = ["bicycle", "bicycle+sensor_bias", "bicycle+tyre_saturation"]
    doc = json.loads(run_tool("compare", RUN.name, "--vehicle", VEHICLE.name,
                              *[a for m in models for a in ("--model", m)], "--json").stdout)
    entries = {e["model"]: e for e in doc["models"]}
    assert set(entries) == set(models)
    drift, tol = heading_drift(data())
    bias_r = entries["bicycle+sensor_bias"]["params"]["bias_r"]
    # a fitted (not named) bias may be wide, but its interval must reach what the heading allows
    lo, hi = bias_r.get("ci95") or (-np.inf, np.inf)
    assert lo - tol <= drift <= hi + tol, (bias_r, drift, tol)
    text = run_tool("compare", RUN.name, "--vehicle", VEHICLE.name, *[a for m in models for a in ("--model", m)]).stdout
    check_speed_words(text)


@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason=WAITS_FOR_SOLVER_HONESTY)
def test_stid_compare_never_shows_a_failed_fit_as_a_result():
    models = ["bicycle", "bicycle+tyre_saturation"]
    doc = json.loads(run_tool("compare", RUN.name, "--vehicle", VEHICLE.name,
                              *[a for m in models for a in ("--model", m)], "--json").stdout)
    base, more = (next(e for e in doc["models"] if e["model"] == m) for m in models)
    if any(more["fit"][o] < base["fit"][o] - 0.5 for o in ("ay", "r")):
        assert more.get("converged") is False, more


@pytest.mark.slow
def test_stid_report_as_a_command_tells_the_same_story(tmp_path, diagnosis):
    import html

    doc, _ = diagnosis
    run_tool("report", RUN.name, "--vehicle", VEHICLE.name, "-o", tmp_path / "rep")
    page = html.unescape((tmp_path / "rep" / "report.html").read_text())
    m = re.search(r"model bicycle: fit ay ([0-9.]+)%, r ([0-9.]+)%", page)
    assert m, "no fit line for bicycle on the page"
    assert (float(m.group(1)), float(m.group(2))) == (round(doc["fit"]["ay"], 1), round(doc["fit"]["r"], 1)), m
    text = re.sub(r"<[^>]+>", " ", page)
    check_speed_words(text)
    for effect in named_effects(doc):
        assert effect in text, effect


@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason=WAITS_FOR_WORDS)
def test_stid_report_words_point_to_what_is_there(tmp_path):
    import html

    run_tool("report", RUN.name, "--vehicle", VEHICLE.name, "-o", tmp_path / "rep")
    text = re.sub(r"<[^>]+>", "\n", html.unescape((tmp_path / "rep" / "report.html").read_text()))
    check_every_see_below_has_its_section(text)
    check_no_stray_unit(text)
