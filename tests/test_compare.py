"""`stid compare` and the command line a person reads once: headers above the rows, full
model names, a verdict, --validate (fit on some runs, judge on another), `fit` far
below the floor pointing to diagnose, --version, the effect list in --help, a closed
pipe ending quietly."""

from __future__ import annotations

import json
import subprocess

import numpy as np

from conftest import REPO, tool
from simdata import random_steer_pair

RC8 = str(REPO / "docs" / "examples" / "rc8.toml")


def _stid(*args, timeout=300):
    return subprocess.run([tool("stid"), *map(str, args)], capture_output=True, text=True, timeout=timeout)


def test_compare_validates_on_a_run_it_was_not_fitted_to(simdir):
    fit_on, judge_on = random_steer_pair(simdir, ("actuator_lag",))
    r = _stid("compare", fit_on, "--validate", judge_on, "--vehicle", RC8, "--model", "bicycle",
              "--model", "bicycle+actuator_lag")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("model "))
    assert "fit ay" in lines[head] and "bicycle+actuator_lag" in lines[head + 2]  # header above, full name
    assert f"judged on {judge_on} (not fitted to)" in r.stdout  # as given: another folder's rs5.mcap is not a fitted one
    verdict = next(line for line in lines if line.startswith("verdict:"))
    assert "bicycle+actuator_lag is the best" in verdict and "noise floor" in verdict
    # the per-run table lists only the held-out run: the numbers are judged there
    per_run = r.stdout.split("fit per run")[1]
    assert judge_on.name in per_run and fit_on.name not in per_run
    j = _stid("compare", fit_on, "--validate", judge_on, "--vehicle", RC8, "--model", "bicycle+actuator_lag",
              "--json")
    doc = json.loads(j.stdout)["models"][0]
    assert doc["validated_on"] == [judge_on.name] and doc["fit"]["ay"] > 95
    # short of the floor on the held-out run, the next command diagnoses that run (a trial's compare
    # sent it back to the fitted runs, where the model was already at the floor)
    short = _stid("compare", fit_on, "--validate", judge_on, "--vehicle", RC8, "--model", "bicycle")
    assert "short of the noise floor on the held-out run:" in short.stdout, short.stdout
    assert f"next: stid fit {judge_on}" in short.stdout, short.stdout


def test_fit_far_below_the_floor_says_so_and_points_to_diagnose(simdir):
    paths = random_steer_pair(simdir, ("actuator_lag",))
    r = _stid("fit", *paths, "--vehicle", RC8, "--model", "bicycle")
    assert r.returncode == 0, r.stderr
    assert "far below the noise floor" in r.stdout and "stid diagnose" in r.stdout
    js = json.loads(_stid("fit", *paths, "--vehicle", RC8, "--model", "bicycle", "--json").stdout)
    # a script that reads the warnings hears it too (a trial's had only below_floor to go by)
    assert js["below_floor"] and any("far below the noise floor" in w for w in js["warnings"]), js["warnings"]
    ok = _stid("fit", paths[1], "--vehicle", RC8, "--model", "bicycle+actuator_lag", "--validate", paths[0])
    assert ok.returncode == 0 and "far below" not in ok.stdout and "judged on" in ok.stdout
    # judging on a run the fit saw is not validation: refused, in one line
    same = _stid("fit", *paths, "--vehicle", RC8, "--model", "bicycle+actuator_lag", "--validate", paths[0])
    assert same.returncode == 2 and "the same data as a run fitted to" in same.stderr and "Traceback" not in same.stderr


def test_the_same_model_twice_is_refused(simdir):
    """Two identical rows (the effects in another order are the same model) read as two results."""
    paths = random_steer_pair(simdir, ("actuator_lag",))
    r = _stid("compare", *paths, "--vehicle", RC8, "--model", "bicycle+actuator_lag+accel_offset",
              "--model", "bicycle+accel_offset+actuator_lag")
    assert r.returncode == 2 and "are the same model" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_version_help_and_a_closed_pipe():
    for args in (["--version"], ["fit", "--version"], ["diagnose", "--version"]):
        r = _stid(*args)
        assert r.returncode == 0 and r.stdout.startswith("stid "), (args, r.stdout, r.stderr)
    for command in ("stid-log", "stid-sim"):  # every command a user types
        r = subprocess.run([tool(command), "--version"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and r.stdout.startswith(f"{command} "), (command, r.stdout, r.stderr)
    h = _stid("--help")
    assert "A first session" in h.stdout
    for effect in ("actuator_lag", "tyre_relaxation", "accel_offset", "body_roll", "tyre_saturation", "sensor_bias"):
        assert f"  {effect}:" in h.stdout
    # a reader that went away before the command wrote: no traceback, no complaint
    p = subprocess.Popen([tool("stid"), "plan", "--vehicle", RC8, "--manoeuvre", "speed=4,amp=2deg,bw=4,dur=10"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.stderr.read()
    p.wait(timeout=120)
    assert err == b"" and p.returncode == 0, err


def test_the_verdict_on_one_model_compares_it_with_the_floor_alone():
    from stid.present import _verdict

    def entry(name, ay, r, bic):
        return {"model": name, "fit": {"ay": ay, "r": r}, "bic": bic, "noise_floor": {"ay": 99.0, "r": 98.0},
                "noise_floor_stderr": {"ay": 0.1, "r": 0.1}}

    one = _verdict([entry("bicycle", 60.0, 90.0, 0.0)])
    assert one.startswith("verdict: bicycle stays ay 39.0 points") and "best of these" not in one
    assert _verdict([entry("bicycle", 98.9, 97.95, 0.0)]) == ("verdict: bicycle reaches the noise floor: nothing "
                                                              "more this data can show")
    two = _verdict([entry("bicycle", 60.0, 90.0, 0.0), entry("bicycle+actuator_lag", 98.9, 97.9, -10.0)])
    assert two.startswith("verdict: bicycle+actuator_lag is the best of these by BIC and reaches")


def test_a_floor_the_data_do_not_determine_is_not_given_and_nothing_claims_to_reach_it():
    """On a circle at constant steer the floor came out 68% +- 28 where the bicycle fits 99.5%, and
    was printed as 'what a correct model reaches'; compare's verdict then said the model 'reaches
    the noise floor'. A floor whose standard error exceeds UNDETERMINED_SE points is not given."""
    import numpy as np

    from stid.analysis.noise_floor import UNDETERMINED_SE, _floor_from
    from stid.analysis.noise_floor import floor_words
    from stid.present import _verdict

    rng = np.random.default_rng(0)
    y = rng.standard_normal(5000)
    folds = np.repeat(np.arange(5), 1000)
    steady = y * (0.01 + 0.6 * (folds == 2))  # one fold's error is 60% of the signal, the others 1%
    floor, se = _floor_from(({"ay": [steady], "r": [0.01 * y]}, {"ay": [y], "r": [y]}, [folds]))
    assert se["ay"] > UNDETERMINED_SE and np.isnan(floor["ay"]) and floor["r"] > 98
    words = floor_words(floor, se)
    assert words.startswith(f"noise floor r {floor['r']:.1f}% (what a correct model reaches here); ay not "
                            "determined by this data (standard error") and "nan" not in words, words
    entry = {"model": "bicycle", "fit": {"ay": 99.5, "r": 90.0}, "bic": 0.0, "noise_floor": floor,
             "noise_floor_stderr": se}
    assert _verdict([entry]).startswith("verdict: bicycle stays r ")  # r's floor still judges r
    entry["fit"]["r"] = floor["r"]
    assert "reaches the noise floor of r (there is none for the other)" in _verdict([entry])
    entry["noise_floor"] = {"ay": float("nan"), "r": float("nan")}
    assert "reaches" not in _verdict([entry]) and "no noise floor on this data" in _verdict([entry])


def test_bic_counts_coloured_residuals_by_their_effective_number():
    """Two models whose residuals are coloured (an AR(1) of correlation time ~40 samples), the one
    with a parameter more leaving 0.1% less variance: counted as independent, 16,000 samples make
    that worth 16 > ln(16,000) = 9.7, and the richer model won ('the best of these by BIC' for a
    0.12 ms delay of none, on a trial user's car); counted by their effective number (as a
    diagnosis's likelihood ratio counts them) it is worth 0.4 < ln(205), and the simpler one wins."""
    from types import SimpleNamespace

    from stid.compare import _effective_bic
    from stid.fit.result import Prediction

    rng = np.random.default_rng(3)
    n, rho = 8000, 0.95
    e = np.zeros((n, 2))
    for k in range(1, n):
        e[k] = rho * e[k - 1] + rng.standard_normal(2)
    y = np.zeros((n, 2))

    def entry(scale, k):
        pred = Prediction("run", np.arange(n) * 0.005, np.zeros(n), y, y - scale * e, 4.0, np.ones(n, bool))
        res = SimpleNamespace(k=k, n=2 * n, predictions=[pred])
        err = (scale * e)
        loglik = float(-0.5 * n * np.sum(np.log(2 * np.pi * np.mean(err ** 2, axis=0)) + 1))
        return {"_judged": res, "_result": res, "bic": k * np.log(2 * n) - 2 * loglik,
                "_resid": SimpleNamespace(n=n, tau_int={"ay": (1 + rho) / (1 - rho), "r": (1 + rho) / (1 - rho)})}

    simple, rich = entry(1.0, 4), entry(np.sqrt(1 - 1e-3), 5)
    assert rich["bic"] < simple["bic"]  # (raw: the richer model wins)
    _effective_bic([simple, rich])
    assert simple["bic_effective"] < rich["bic_effective"] and simple["effective_samples"] == 205  # 8000 / 39


def test_an_effect_that_gains_nothing_is_not_the_best_by_bic(tmp_path):
    """Exact single-track bags with a servo lag and no delay: bicycle+actuator_lag+sensor_delay's
    delay ends on its bound and gains no fit point; the verdict (by BIC on effective samples) names
    the model without it."""
    import ros_data as rd

    d = rd.drive(duration=40.0, imu_hz=200, imu_offset_ms=2, servo_tau=0.05, seed=7)
    bag = rd.write_bag(d, tmp_path / "run", rd.Layout())
    car = rd.vehicle_toml(tmp_path / "car.toml", "[sensors]\naccel_bandwidth_hz = 0\ngyro_bandwidth_hz = 0\n")
    r = _stid("compare", bag, "--vehicle", car, "--model", "bicycle+actuator_lag",
              "--model", "bicycle+actuator_lag+sensor_delay", "--json")
    assert r.returncode == 0, r.stderr
    rows = {e["model"]: e for e in json.loads(r.stdout)["models"]}
    lag, more = rows["bicycle+actuator_lag"], rows["bicycle+actuator_lag+sensor_delay"]
    assert max(abs(more["fit"][o] - lag["fit"][o]) for o in ("ay", "r")) < 0.1  # (it gains nothing)
    assert lag["bic_effective"] < more["bic_effective"], (lag["bic_effective"], more["bic_effective"])
    text = _stid("compare", bag, "--vehicle", car, "--model", "bicycle+actuator_lag",
                 "--model", "bicycle+actuator_lag+sensor_delay").stdout
    assert "verdict: bicycle+actuator_lag is the best of these" in text, text
