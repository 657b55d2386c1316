"""``stid compare``: fit several models to the same runs and show where each fails:
fit percent per frequency band, per |ay| bin (linear range vs the friction limit) and
per run, residual whiteness, and a verdict. Every model is fitted by the one path
``stid fit`` uses (stid.fit.fitting.fit), so the numbers are the ones ``fit`` prints."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stid.errors import InputError
from stid.fit.result import fit_percent

BANDS_HZ = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0))
OUTS = ("ay", "r")


@dataclass
class Breakdown:
    by_band: dict = field(default_factory=dict)  # "1-2 Hz" -> {"ay": %, "r": %}
    by_ay: dict = field(default_factory=dict)  # "|ay| 2-4 m/s^2" -> {...}
    by_run: dict = field(default_factory=dict)  # "run (4.0 m/s)" -> {...}


def band_fit(y: np.ndarray, yhat: np.ndarray, fs: float, lo: float, hi: float) -> float:
    """Fit percent of the part of y between lo and hi Hz: the residual's energy there
    against the signal's (Parseval on one Hann-windowed periodogram; the ratio of two
    energies in the same band needs no averaging of spectra)."""
    w = np.hanning(len(y))
    f = np.fft.rfftfreq(len(y), 1.0 / fs)
    Pe = np.abs(np.fft.rfft((y - yhat - np.mean(y - yhat)) * w)) ** 2
    Py = np.abs(np.fft.rfft((y - y.mean()) * w)) ** 2
    m = (f >= lo) & (f < hi) & (f > 0)
    if not m.any() or Py[m].sum() <= 0:
        return float("nan")
    return float(100 * (1 - np.sqrt(Pe[m].sum() / Py[m].sum())))


def breakdown(predictions, ay_edges=(0.0, 2.0, 4.0, 6.0, np.inf)) -> Breakdown:
    out = Breakdown()
    y = np.vstack([p.y[p.keep] for p in predictions])
    yh = np.vstack([p.yhat[p.keep] for p in predictions])
    fs = 1.0 / float(predictions[0].t[1] - predictions[0].t[0])
    for lo, hi in BANDS_HZ:
        vals = {}
        for i, o in enumerate(OUTS):
            parts = [band_fit(p.y[p.keep, i], p.yhat[p.keep, i], fs, lo, hi) for p in predictions]
            w = [int(p.keep.sum()) for p in predictions]
            ok = [(v, n) for v, n in zip(parts, w) if np.isfinite(v)]
            vals[o] = float(np.average([v for v, _ in ok], weights=[n for _, n in ok])) if ok else float("nan")
        out.by_band[f"{lo:g}-{hi:g} Hz"] = vals
    a = np.abs(y[:, 0])
    for lo, hi in zip(ay_edges[:-1], ay_edges[1:]):
        m = (a >= lo) & (a < hi)
        if m.sum() < 50:
            continue
        # fit of the samples in the bin, against the variation of the whole output
        out.by_ay[f"|ay| {lo:g}-{hi:g} m/s^2" if np.isfinite(hi) else f"|ay| > {lo:g} m/s^2"] = {
            o: float(100 * (1 - np.sqrt(np.mean((y[m, i] - yh[m, i]) ** 2) / np.var(y[:, i]))))
            for i, o in enumerate(OUTS)}
    for p in predictions:
        out.by_run[f"{p.name} ({p.vx:.1f} m/s)"] = {o: fit_percent(p.y[p.keep, i], p.yhat[p.keep, i])
                                                    for i, o in enumerate(OUTS)}
    return out


def compare(runs, vehicle, models: list[str], method: str = "time", progress=None, validate=None) -> list[dict]:
    """Fit each model to ``runs``; with ``validate`` (other runs) judge every number on those,
    the parameters held at the fit's."""
    from stid.analysis.noise_floor import noise_floor_uncertainty, submit_floor
    from stid.fit import dataset
    from stid.models.model import Model
    from stid.workers import worker_pool

    # names checked before any data work; a model given twice (its effects in any order) is
    # the same model: two identical rows would read as two results
    seen = {}
    for name in models:
        m = Model(name, vehicle)
        key = (m.base, frozenset(e.name for e in m.effects))
        if key in seen:
            raise InputError(f"--model {seen[key]} and --model {name} are the same model: give each model once")
        seen[key] = name
    stretches = dataset.dynamic_stretches(runs) if method == "time" else None
    held = dataset.held_out_stretches(validate) if validate else None
    judged_on = held if held is not None else (stretches if stretches is not None else dataset.dynamic_stretches(runs))
    with worker_pool(1) as pool:  # the noise floor needs only the data: on the other core, beside the fits
        floor = submit_floor(pool, judged_on) if pool else None
        entries = _fit_each(runs, vehicle, models, method, progress, validate, stretches, held)
        floor, floor_se = floor.result() if floor is not None else noise_floor_uncertainty(judged_on)
    for e in entries:
        e["noise_floor"], e["noise_floor_stderr"] = floor, floor_se
    _effective_bic(entries)
    return entries


def _effective_bic(entries) -> None:
    """Each entry's BIC with the residuals' effective sample size (``bic_effective``): the samples
    over their integrated autocorrelation time, the most coloured model's, the same for all (as a
    diagnosis's likelihood ratio counts them). Counted as independent, the samples of coloured
    residuals made any gain a win: a delay of 0.12 ms (z = 2), gaining no fit point, was 'the best
    of these by BIC' on a trial user's car that had none."""
    tau = max((max(e["_resid"].tau_int.values()) for e in entries), default=1.0)
    n_eff = max(entries[0]["_resid"].n / max(tau, 1.0), 1.0) if entries else 1.0
    for e in entries:
        judged = e["_judged"]
        err = np.vstack([p.y[p.keep] - p.yhat[p.keep] for p in judged.predictions])
        var = np.maximum(np.mean(err ** 2, axis=0), 1e-300)
        e["bic_effective"] = float(e["_result"].k * math.log(n_eff) + n_eff * np.sum(np.log(var)))
        e["effective_samples"] = round(n_eff)


def _fit_each(runs, vehicle, models, method, progress, validate, stretches, held) -> list[dict]:
    from stid.analysis.residuals import analyse
    from stid.fit import nested
    from stid.fit.fitting import fit
    from stid.fit.validate import judge_on
    from stid.models.model import Model

    entries, done = [], {}
    for name in models:
        if progress:
            progress.step(name)
        # a model with effects starts from the bicycle's solution: the row above, when it is there
        res = fit(runs, vehicle, name, method, stretches=stretches, inner=done.get(nested.BASE))
        done[res.model] = res
        judged = judge_on(res, Model(name, vehicle), held) if held is not None else res
        ra = analyse(judged.predictions)
        bd = breakdown(judged.predictions)
        entries.append({
            "model": res.model, "method": res.method, "fit": judged.fit, "aic": res.aic, "bic": res.bic,
            "converged": res.converged, "status": res.status,
            "validated_on": [r.name for r in validate] if validate else None,
            "params": {n: d for n, d in res.params_json().items() if n in res.names},
            "white": {o: ra.white(o) for o in OUTS},
            "independent": {o: ra.independent(o) for o in OUTS},
            "by_band": bd.by_band, "by_ay": bd.by_ay, "by_run": bd.by_run, "warnings": res.warnings,
            "_result": res, "_judged": judged, "_resid": ra,
        })
    return entries
