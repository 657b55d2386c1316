"""Frequency-domain fits of the responses ay/delta and r/delta.

Two costs:

- ``wls`` (default): weighted least squares on real and imaginary parts, each
  point weighted by the inverse variance of the H1 estimate from its coherence
  and the number of averages. Its covariance is an honest parameter
  uncertainty.
- ``study``: the cost of study (1): squared complex error weighted by coherence
  and normalised per output by the mean measured magnitude. Kept to reproduce the
  study; its scaling has no statistical meaning, so its covariance is only the
  white-residual approximation.
"""

from __future__ import annotations

import numpy as np

from stid.fit.dataset import Stretch, check_excitation
from stid.fit.frf import FRF, estimate_frf
from stid.fit.solver import ParamSpace, starting_points, covariance_white, least_squares, to_physical
from stid.fit.result import Prediction
from stid.fit.time_fit import make_result, _keep
from stid.fit import checks, convergence


def frf_residual(model, p: dict, frfs: list[FRF], weighting: str) -> np.ndarray:
    out = []
    for fr in frfs:
        Hm = model.freqresp(p, fr.f, fr.vx, getattr(fr, "sensors", None))
        e = Hm - fr.H
        if weighting == "wls":
            w = 1.0 / np.sqrt(fr.variance())
        else:
            w = np.sqrt(np.clip(fr.coh, 0, 1) / np.mean(np.abs(fr.H), axis=1, keepdims=True))
        e = e * w
        out.append(np.concatenate([e.real.ravel(), e.imag.ravel()]))
    return np.concatenate(out)


def fit_freq(model, stretches: list[Stretch], fixed: dict | None = None, init: dict | None = None,
             weighting: str = "wls", space: ParamSpace | None = None, method_name: str | None = None,
             frfs: list[FRF] | None = None):
    fixed = dict(fixed or {})
    warnings = check_excitation(stretches)
    frfs = frfs or [estimate_frf(s) for s in stretches]
    for fr in frfs:
        if len(fr.f) < 5:
            warnings.append(f"{fr.name}: the steer excites only {len(fr.f)} frequency lines; "
                            "drive random steer with a wider bandwidth")
        elif np.mean(fr.coh) < 0.5:
            warnings.append(f"{fr.name}: low coherence (mean {np.mean(fr.coh):.2f}): noisy or nonlinear response")
    if space is None:
        space = ParamSpace(model, [n for n in model.param_names if n not in fixed], fixed)
    p0 = model.defaults()
    p0.update(init or {})
    p0.update(fixed)
    starts = starting_points(model, space, p0, bool(model.effects))
    res = least_squares(lambda p: frf_residual(model, p, frfs, weighting), space, starts)
    p_hat = space.to_p(res.x)
    col = np.linalg.norm(res.jac, axis=0)
    blind = [n for n, c in zip(space.free, col) if c < 1e-9 * max(col.max(), 1e-300)]
    if blind:
        warnings.append(f"{', '.join(blind)} do not change the frequency responses (means and constant "
                        "offsets are removed before spectra are taken): not identifiable by this method; "
                        "use --method time")
    cov = to_physical(covariance_white(res.jac, res.fun, len(space.free)), space, res.x)
    preds = [Prediction(s.name, s.t, s.steer, s.y, model.simulate(p_hat, s.steer, s.dt, s.vx_series, sensors=s.sensors), s.vx,
                        _keep(s, 0.5)) for s in stretches]
    result = make_result(model, method_name or f"freq ({weighting})", space, p_hat, cov, preds)
    result.set_verdict(convergence.judge(res, space))
    result.extra["frfs"] = frfs
    dof = max(len(res.fun) - len(space.free), 1)
    result.extra["chi2_red"] = float(res.fun @ res.fun / dof)
    result.interval = ("95% intervals: noise only (from the frequency-response fit's Jacobian and residuals, "
                       "inflated by the reduced chi-square when the model misses them); --method time also "
                       "widens them for model error")
    for w in warnings:
        result.warn(w)
    for note in getattr(stretches, "notes", []):  # what was left out, the sensor chain assumed
        result.note(note)
    for n in space.at_bound(res.x):
        result.warn(f"{n} stopped at its bound ({p_hat[n]:.4g} {model.param(n).unit})")
    checks.add_identifiability_warnings(result, model, stretches)
    return result
