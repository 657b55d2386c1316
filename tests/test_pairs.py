"""Two effects at once: a servo lag bent by a second effect is fitted jointly with every other
catalogue effect before anything is called missing (stid.search.pairs). The runs are written
here from plain physics (tests/pair_physics.py), apart from stid's models, on a 1:10 car on a
track at 3 and 7 m/s, 100 Hz, 30 s each."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from pair_physics import Car10, pair_runs
from stid.diagnose import diagnose
from stid.models.effect import available_effects

# a 60 ms servo lag with a spool (Cx 200 N per unit slip over a 0.2 m track): alone, the lag
# fits 59 ms at 3 m/s and 78 ms at 7 m/s, and from the bicycle the spool looks like chance
LAG_SPOOL = Car10(tau=0.060, Cx=200.0)
# a 40 ms servo lag with a degressive linkage (k3 = -3 /rad^2: twice hil_sim's short horn on long
# arms, whose mechanism fits -1.5; the wheels stop turning further at 0.33 rad), steered 5 deg rms at
# 3 m/s and 1.5 deg at 7 m/s (less at speed, as a driver does). (It was -5, the catalogue's bound: a
# truth on a bound gets no interval by the contract, so no order of the chain could cover it.)
LAG_LINKAGE = Car10(tau=0.040, k3=-3.0)
CASES = {"actuator_lag+locked_diff": (LAG_SPOOL, {}),
         "actuator_lag+steering_nonlinearity": (LAG_LINKAGE, {"rms_deg": (5.0, 1.5)})}


@functools.lru_cache(maxsize=2)  # (the default tests share one case; the slow one makes 30 each)
def _case(name, seed):
    car, kw = CASES[name]
    effects = tuple(name.split("+"))
    return car, effects, pair_runs(car, effects, seed, **kw)


def test_a_servo_lag_bent_by_a_locked_diff_is_named_with_it():
    """The lag alone is not one value across speed; fitted jointly with the locked diff both
    hold, and the pair is named in one round, with the truth inside the joint intervals. The
    JSON names the pair and accounts for every other catalogue effect as a partner."""
    car, effects, runs = _case("actuator_lag+locked_diff", 1)
    (d,) = diagnose(runs, car.vehicle(), "bicycle")
    best = d.best
    table = [(c.effect, c.why_not) for c in d.candidates]
    assert best is not None and best.effect == "actuator_lag", table
    assert "not one value across speed" in best.evidence_alone.reason, best.evidence_alone.reason
    assert d.named == ["actuator_lag", "locked_diff"], table
    assert d.named_model == "bicycle+actuator_lag+locked_diff"
    joint = d.named_result
    ci = dict(zip(joint.names, joint.ci95))
    for name, truth in car.truth(effects).items():
        lo, hi = ci[name]
        assert lo <= truth <= hi or abs(joint.value(name) / truth - 1) < 0.02, (name, truth, joint.value(name), lo, hi)
    doc = json.loads(json.dumps(d.to_json()))
    assert doc["named"] == ["actuator_lag", "locked_diff"]
    top, second = doc["candidates"][:2]
    assert top["effect"] == "actuator_lag" and top["named_with"] == "locked_diff" and top["significant"]
    assert second["effect"] == "locked_diff" and second["named_with"] == "actuator_lag" and second["significant"]
    tried = {t["effect"]: t for t in top["pairs"]["tried"]}
    assert tried["locked_diff"]["verdict"] == "named"
    assert {"tau_steer", "k_diff"} <= set(tried["locked_diff"]["params"])
    others = set(available_effects()) - {"actuator_lag"}
    assert set(tried) == others, sorted(others - set(tried))


def test_the_catalogue_lacks_it_only_after_the_pairs_and_says_which(tmp_path):
    """The same car with the locked diff left out of the catalogue offered: no pair holds, so
    the gap is unexplained, and the words and the JSON say which pairs were tried first."""
    from stid.present import diagnosis_text

    car, _, runs = _case("actuator_lag+locked_diff", 1)
    offered = ["actuator_lag", "sensor_delay", "tyre_relaxation", "body_roll"]
    (d,) = diagnose(runs, car.vehicle(), "bicycle", candidates=offered)
    assert d.best is None, [(c.effect, c.why_not) for c in d.candidates]
    lag = next(c for c in d.candidates if c.effect == "actuator_lag")
    assert lag.passes and lag.pairs is not None
    u = d.unexplained
    assert u.significant
    said = next(w for w in u.where if w.startswith("pairs tried with actuator_lag"))
    for e in ("sensor_delay", "tyre_relaxation", "body_roll"):
        assert e in said, said
    doc = u.to_json()
    assert {t["effect"] for t in doc["pairs_tried"]["actuator_lag"]["tried"]} == set(offered) - {"actuator_lag"}
    text = diagnosis_text([d])
    assert "alone or paired with actuator_lag" in text and "an effect the catalogue lacks" in text, text
    assert text.index("pairs tried with actuator_lag") < text.index("an effect the catalogue lacks")


# Measured (30 seeds each, 2026-11-26): lag + spool: named right 30/30; Cf, Cr, Iz, k_diff
# covered 100%, tau 97%. Lag + linkage: named right 30/30; Cf, Cr, Iz, tau_steer, k3 covered 100%
# (before the model ran the linkage behind the servo's lag, as the car and hil_sim do, k3 was
# covered 3%: it fitted -12.7% noise-free; tests/test_steering_chain.py has the short version).


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_intervals_after_diagnosis_hold_the_truth_over_seeds(case):
    """Over 30 seeds, `diagnose --peel` names both effects (in one round or two) in at least 90%
    of them, and the final model's 95% intervals hold each true parameter in at least 90%
    (a seed where the parameter's effect is not named counts as a miss)."""
    n = 30
    named_right, held = 0, {}
    for seed in range(100, 100 + n):
        car, effects, runs = _case(case, seed)
        rounds = diagnose(runs, car.vehicle(), "bicycle", peel=True)
        named = [e for d in rounds for e in d.named]
        named_right += sorted(named) == sorted(effects)
        final = next((d.named_result for d in reversed(rounds) if d.best is not None), rounds[0].base)
        ci = dict(zip(final.names, final.ci95))
        for name, truth in car.truth(effects).items():
            lo, hi = ci.get(name, (np.nan, np.nan))
            held.setdefault(name, []).append(bool(lo <= truth <= hi))
    rates = {k: sum(v) / n for k, v in held.items()}
    print(case, "named right", named_right / n, "coverage", rates)
    assert named_right / n >= 0.9, (named_right, n)
    assert all(r >= 0.9 for r in rates.values()), rates


def test_a_pair_is_held_to_the_kinematics_as_a_candidate_alone_is(simdir, rc_vehicle, monkeypatch):
    """A candidate alone is not named when the data's kinematics rule out its sensor offsets
    (stid.analysis.kinematics); a partner in the pair search was named without that check. Here
    the check is made to refuse the accelerometer's place: the servo lag and accelerometer offset
    the demo's runs hide are then not named as a pair, and the pair says why."""
    from stid.analysis import kinematics
    from stid.load import load_runs
    from stid.search import pairs
    from simdata import random_steer_pair

    monkeypatch.setitem(kinematics.CHECKS, "accel_offset", lambda result, stretches: "the test rules it out")
    runs = load_runs(random_steer_pair(simdir, ("actuator_lag", "accel_offset")), rc_vehicle)
    (d,) = diagnose(runs, rc_vehicle, "bicycle")
    assert "accel_offset" not in d.named, d.named
    lag = next(c for c in d.candidates if c.effect == "actuator_lag")
    tried = {t.partner: t for t in lag.pairs.tried}
    assert tried["accel_offset"].verdict == pairs.RULED_OUT, (tried["accel_offset"].verdict, tried["accel_offset"].why)
    assert "the test rules it out" in tried["accel_offset"].why
