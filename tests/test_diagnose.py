"""stid diagnose on simulated data with hidden effects (the simulator and the
identifier were written apart: the diagnosis does not know the answer)."""

import json
import subprocess

import pytest

from conftest import REPO, tool
from simdata import TRUTH, random_steer_pair, sim_run
from stid.diagnose import diagnose
from stid.load import load_runs
from test_identification import EFFECT_DATA, EFFECT_TRUTH, rel_err

BASE = {"Cf": TRUTH.Cf, "Cr": TRUTH.Cr, "Iz": TRUTH.Iz}


@pytest.mark.parametrize("effect", sorted(EFFECT_TRUTH))
def test_hidden_effect_is_named_first_and_the_error_falls_to_the_noise_floor(simdir, rc_vehicle, effect):
    runs = load_runs(random_steer_pair(simdir, (effect,), **EFFECT_DATA.get(effect, {})), rc_vehicle)
    rounds = diagnose(runs, rc_vehicle, "bicycle", peel=True)
    first = rounds[0]
    assert first.candidates[0].effect == effect, [(c.effect, c.significant, c.lr) for c in first.candidates]
    assert first.best is not None and first.best.effect == effect
    assert first.best.explanation
    # with it added: at the noise floor, base parameters within 5% of truth, nothing else missing
    fixed = first.best.result
    for o in ("ay", "r"):
        assert fixed.fit[o] > first.floor[o] - 0.5, (o, fixed.fit, first.floor)
    assert max(rel_err(fixed, BASE).values()) < 0.05, fixed.table()
    assert len(rounds) == 2 and rounds[1].best is None


def test_two_hidden_effects_are_peeled_one_after_the_other(simdir, rc_vehicle):
    effects = ("actuator_lag", "accel_offset")
    runs = load_runs(random_steer_pair(simdir, effects), rc_vehicle)
    rounds = diagnose(runs, rc_vehicle, "bicycle", peel=True)
    found = [d.best.effect for d in rounds if d.best is not None]
    assert sorted(found) == sorted(effects), [(d.model, d.best and d.best.effect) for d in rounds]
    assert rounds[-1].best is None
    final = rounds[-2].best.result
    assert max(rel_err(final, BASE).values()) < 0.05


@pytest.mark.parametrize("seeds", [(11, 12), (13, 14), (15, 16), (17, 18)])
def test_clean_data_has_nothing_significant(simdir, rc_vehicle, seeds):
    runs = load_runs(random_steer_pair(simdir, (), seeds=seeds), rc_vehicle)
    (d,) = diagnose(runs, rc_vehicle, "bicycle")
    assert d.best is None, [(c.effect, c.lr, c.gain) for c in d.candidates if c.significant]


@pytest.mark.slow
def test_false_positive_rate_over_seeds(simdir, rc_vehicle):
    """Measured over 20 independent clean data sets: at most 5% may flag anything."""
    flagged = 0
    n = 20
    for k in range(n):
        runs = load_runs(random_steer_pair(simdir, (), seeds=(100 + 2 * k, 101 + 2 * k)), rc_vehicle)
        (d,) = diagnose(runs, rc_vehicle, "bicycle")
        flagged += d.best is not None
    assert flagged / n <= 0.05


def test_a_short_servo_lag_at_one_speed_is_reported_as_not_separable_from_relaxation(simdir, rc_vehicle):
    """15 ms of servo lag at one speed looks like tyre relaxation (sigma/vx ~ 15 ms): the tool
    must say it cannot tell them apart and which run would, and must not peel past it."""
    from hil_sim.vehicle import CarParams

    path = sim_run(simdir, "random_steer", ("actuator_lag",), seed=7, speed=6.0, car=CarParams(tau_steer=0.015))
    rounds = diagnose(load_runs([path], rc_vehicle), rc_vehicle, "bicycle", peel=True)
    best = rounds[0].best
    assert best.effect in ("actuator_lag", "tyre_relaxation")
    other = "tyre_relaxation" if best.effect == "actuator_lag" else "actuator_lag"
    assert other in best.separable_from
    assert "second speed" in best.explanation and "one speed only" in best.explanation
    assert len(rounds) == 1  # no guessing: peeling stops at an undecidable choice


def test_servo_lag_at_two_speeds_is_named_without_doubt(simdir, rc_vehicle):
    runs = load_runs(random_steer_pair(simdir, ("actuator_lag",)), rc_vehicle)
    (d,) = diagnose(runs, rc_vehicle, "bicycle")
    assert d.best.effect == "actuator_lag" and not d.best.separable_from
    assert "at every speed (4, 6 m/s)" in d.best.explanation


def test_diagnose_cli_json_contract(simdir):
    paths = random_steer_pair(simdir, ("actuator_lag",))
    r = subprocess.run([tool("stid"), "diagnose", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["model"] == "bicycle" and set(doc["fit"]) == {"ay", "r"}
    top = doc["candidates"][0]
    assert top["effect"] == "actuator_lag" and top["significant"] is True
    assert {"fit", "delta_bic", "params", "explanation"} <= set(top)
    assert top["params"]["tau_steer"] == pytest.approx(TRUTH.tau_steer, rel=0.15)
    assert top["delta_bic"] < 0


def test_diagnose_human_output(simdir):
    paths = random_steer_pair(simdir, ("sensor_bias",))
    r = subprocess.run([tool("stid"), "diagnose", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "--peel"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "=> sensor_bias" in r.stdout and "noise floor" in r.stdout
    assert "nothing significant is missing" in r.stdout


def test_compare_shows_where_the_error_lives(simdir, rc_vehicle):
    from stid.compare import compare

    runs = load_runs(random_steer_pair(simdir, ("tyre_saturation",), **EFFECT_DATA["tyre_saturation"]),
                     rc_vehicle)
    plain, sat = compare(runs, rc_vehicle, ["bicycle", "bicycle+tyre_saturation"])
    bins = list(plain["by_ay"])
    low, high = bins[0], bins[-1]
    # the bicycle fails toward the friction limit, the saturating model does not
    assert plain["by_ay"][high]["ay"] < plain["by_ay"][low]["ay"] - 5
    assert sat["by_ay"][high]["ay"] > plain["by_ay"][high]["ay"] + 5
    assert sat["aic"] < plain["aic"] and sat["bic"] < plain["bic"]
    assert len(plain["by_band"]) == 4 and len(plain["by_run"]) == 2
