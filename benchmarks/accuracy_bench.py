"""Accuracy by Monte Carlo over seeds of simulated data (hil_sim, firmware in the loop).

Each seed is a data set of two 40 s random-steer runs (4 and 6 m/s, benchmarks.ident_bench
make_runs), at constant speed or with ``speed_profile="track"`` (the speed target moves
by +-25 % every 2-5 s). Estimators, each named by what reaches it:

- ``stid``: exactly what ``stid fit RUN... --model M`` ships,
  ``stid.fit.fitting.fit(runs, vehicle, M, "auto")`` (default intervals: the wider of the
  Newey-West sandwich and the delete-a-block jackknife, stid.fit.intervals);
- ``study``: study (1)'s method as published (benchmarks/study_method.py: bicycle FRFs
  without sensor dynamics, coherence-weighted cost, Nelder-Mead);
- ``study+sensors``: the same with stid's measurement model, each model FRF through the
  run's declared first-order sensor filters (``python -m benchmarks.study_method
  --sensor-model``; not in the study).

Per parameter: bias, sd over seeds, bias / sd, the standard error of the mean bias
(sd / sqrt(n)), how often the printed 95 % interval contains the truth, the mean printed
standard error against the observed sd; and the predicted sd: the Cramér-Rao bound with
the stand-still's sensor noise, and what ``stid plan`` predicts from a fit's residual
spectrum (stid.plan.noise_from_runs: model error + noise, the output-error sandwich).

One criterion for "unbiased", applied to every estimator alike: the mean error over the
seeds is within 2 standard errors of that mean (|bias| <= 2 sd / sqrt(n)), i.e. the Monte
Carlo cannot tell it from zero. bias / sd says whether a bias matters next to the spread.
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.ident_bench import VEHICLE, make_runs

TRUTH = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}
# the manoeuvre make_runs drives, as `stid plan` takes it (steer_amp is the rms road-wheel angle)
SPEEDS = (4.0, 6.0)
DURATION_S = 40.0
BANDWIDTH_HZ = 4.0


def _make(args):
    d, effects, seeds, amp, profile = args
    return [str(p) for p in make_runs(Path(d), effects, seeds=seeds, steer_amp=amp, speed_profile=profile)]


def datasets(d: Path, n: int, effects=(), first_seed=1000, steer_amp=0.04, speed_profile="constant"):
    jobs = [(str(d), tuple(effects), (first_seed + 2 * k, first_seed + 2 * k + 1), steer_amp, speed_profile)
            for k in range(n)]
    with ProcessPoolExecutor(max_workers=2) as ex:
        return list(ex.map(_make, jobs))


def plan_manoeuvres(steer_amp=0.04):
    from stid.plan import Manoeuvre

    return [Manoeuvre(speed=s, amp=steer_amp, bandwidth=BANDWIDTH_HZ, duration=DURATION_S) for s in SPEEDS]


def _estimate(args):
    paths, model_name, estimators, steer_amp = args
    from benchmarks.study_method import fit_study
    from stid.crlb import crlb, noise_psd_from_still
    from stid.fit import dataset
    from stid.fit.fitting import fit
    from stid.fit.frf import estimate_frf
    from stid.load import load_runs
    from stid.models.model import Model
    from stid.plan import noise_from_fit, predict
    from stid.vehicle_file import load_vehicle

    v = load_vehicle(VEHICLE)
    runs = load_runs(paths, v)
    model = Model(model_name, v)
    out = {}
    ref = None
    for est in estimators:
        if est == "stid":
            res = fit(runs, v, model_name, "auto")  # what `stid fit` runs
            ref = res
            out[est] = res.params()
            out[est + "_se"] = dict(zip(res.names, res.stderr))
            out[est + "_ci"] = {n: (float(lo), float(hi)) for n, (lo, hi) in zip(res.names, res.ci95)}
            out[est + "_method"] = res.method
            # (read from the note's words, this counted the parameters a later allowance widened too)
            widened = res.extra.get("jackknife_widened", [])
            out[est + "_jackknife"] = {n: n in widened for n in res.names}
        elif est in ("study", "study+sensors"):
            st = dataset.dynamic_stretches(runs)
            p, _ = fit_study([estimate_frf(s) for s in st], v, sensor_model=est == "study+sensors")
            out[est] = p
    if ref is None:
        ref = fit(runs, v, model_name, "auto", intervals="noise")
    names = list(ref.names)
    st = dataset.dynamic_stretches(runs)
    inputs = [(s.steer, s.dt, s.vx_series, s.sensors) for s in st]
    still = noise_psd_from_still(runs)
    out["crlb_sd"] = dict(zip(names, np.sqrt(np.diag(crlb(model, ref.all_params(), names, inputs, still)))))
    # what `stid plan --noise-from` predicts for the manoeuvre these runs drove: the fit's residual
    # spectrum (model error + noise) through the output-error sandwich
    noise = noise_from_fit(ref)
    pred = predict(model, ref.all_params(), plan_manoeuvres(steer_amp), noise, names=names)
    out["plan_sd"] = {k: float(x) for k, x in pred["sd"].items()}
    pred_still = predict(model, ref.all_params(), plan_manoeuvres(steer_amp), still, names=names)
    out["plan_still_sd"] = {k: float(x) for k, x in pred_still["sd"].items()}
    return out


def summarise(results: list, estimators, truth=TRUTH) -> dict:
    n = len(results)
    summary = {"n": n}
    for est in estimators:
        summary[est] = {}
        for k, t in truth.items():
            v = np.array([r[est][k] for r in results])
            sd = float(v.std(ddof=1))
            bias = float(v.mean() - t)
            s = {"mean": float(v.mean()), "bias": bias, "bias_pct": 100 * bias / t, "sd": sd,
                 "bias_over_sd": bias / sd if sd > 0 else math.inf,
                 "bias_over_sem": bias / (sd / math.sqrt(n)) if sd > 0 else math.inf}
            s["unbiased"] = abs(s["bias_over_sem"]) <= 2.0
            if est + "_se" in results[0]:
                se = np.array([r[est + "_se"][k] for r in results])
                s["mean_reported_se"] = float(se.mean())
                s["se_over_sd"] = float(se.mean() / sd)
            if est + "_ci" in results[0]:
                inside = [r[est + "_ci"][k][0] <= t <= r[est + "_ci"][k][1] for r in results]
                s["coverage"] = float(np.mean(inside))
                s["jackknife_share"] = float(np.mean([r[est + "_jackknife"][k] for r in results]))
            summary[est][k] = s
    for key in ("crlb_sd", "plan_sd", "plan_still_sd"):
        if key in results[0]:
            summary[key] = {k: float(np.mean([r[key][k] for r in results])) for k in truth}
    return summary


def monte_carlo(d: Path, n: int, effects=(), model_name="bicycle", estimators=("stid", "study", "study+sensors"),
                first_seed=1000, steer_amp=0.04, speed_profile="constant"):
    sets = datasets(d, n, effects, first_seed, steer_amp, speed_profile)
    with ProcessPoolExecutor(max_workers=2) as ex:
        results = list(ex.map(_estimate, [(p, model_name, estimators, steer_amp) for p in sets]))
    return summarise(results, estimators), results
