"""Accuracy by Monte Carlo over seeds of simulated data: bias and standard deviation
of each estimator, against the Cramér-Rao lower bound from the model's sensitivities
and the noise level (stid.crlb)."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.ident_bench import VEHICLE, make_runs

TRUTH = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}


def _make(args):
    d, effects, seeds, amp = args
    return [str(p) for p in make_runs(Path(d), effects, seeds=seeds, steer_amp=amp)]


def datasets(d: Path, n: int, effects=(), first_seed=1000, steer_amp=0.04):
    jobs = [(str(d), tuple(effects), (first_seed + 2 * k, first_seed + 2 * k + 1), steer_amp) for k in range(n)]
    with ProcessPoolExecutor(max_workers=2) as ex:
        return list(ex.map(_make, jobs))


def _estimate(args):
    paths, model_name, estimators = args
    from benchmarks.study_method import fit_study
    from stid.crlb import crlb, noise_psd_from_residuals, noise_psd_from_still
    from stid.fit import dataset
    from stid.fit.freq_fit import fit_freq
    from stid.fit.frf import estimate_frf
    from stid.fit.time_fit import fit_time
    from stid.load import load_runs
    from stid.models.model import Model
    from stid.vehicle_file import load_vehicle

    v = load_vehicle(VEHICLE)
    runs = load_runs(paths, v)
    st = dataset.dynamic_stretches(runs)
    model = Model(model_name, v)
    out = {}
    ref = None
    for est in estimators:
        if est == "stid":
            res = fit_time(model, st, whiten=True)
            ref = res
        elif est == "time":
            res = fit_time(model, st)
        elif est == "freq":
            res = fit_freq(model, st)
        elif est == "study":
            p, _ = fit_study([estimate_frf(s) for s in st], v)
            out[est] = p
            continue
        out[est] = res.params()
        out[est + "_se"] = dict(zip(res.names, res.stderr))
    ref = ref or fit_time(model, st)
    names = list(ref.names)
    inputs = [(s.steer, s.dt, s.vx) for s in st]
    still = noise_psd_from_still(runs)
    cov = crlb(model, ref.all_params(), names, inputs, still)
    out["crlb_sd"] = dict(zip(names, np.sqrt(np.diag(cov))))
    cov_r = crlb(model, ref.all_params(), names, inputs, noise_psd_from_residuals(ref.predictions))
    out["crlb_resid_sd"] = dict(zip(names, np.sqrt(np.diag(cov_r))))
    return out


def monte_carlo(d: Path, n: int, effects=(), model_name="bicycle", estimators=("stid", "study"), first_seed=1000,
                steer_amp=0.04):
    sets = datasets(d, n, effects, first_seed, steer_amp)
    with ProcessPoolExecutor(max_workers=2) as ex:
        results = list(ex.map(_estimate, [(p, model_name, estimators) for p in sets]))
    summary = {}
    for est in estimators:
        vals = {k: np.array([r[est][k] for r in results]) for k in TRUTH}
        summary[est] = {k: {"mean": float(v.mean()), "bias_pct": float(100 * (v.mean() / TRUTH[k] - 1)),
                            "sd": float(v.std(ddof=1))} for k, v in vals.items()}
        if est + "_se" in results[0]:
            for k in TRUTH:
                summary[est][k]["mean_reported_se"] = float(np.mean([r[est + "_se"][k] for r in results]))
    summary["crlb_sd"] = {k: float(np.mean([r["crlb_sd"][k] for r in results])) for k in TRUTH}
    summary["crlb_resid_sd"] = {k: float(np.mean([r["crlb_resid_sd"][k] for r in results])) for k in TRUTH}
    summary["n"] = n
    return summary, results
