"""``stid compare``: fit several models to the same runs and show where each fails."""

from __future__ import annotations

from stid.analysis.compare import breakdown
from stid.analysis.noise_floor import noise_floor
from stid.analysis.residuals import analyse
from stid.fit import dataset
from stid.fit.freq_fit import fit_freq
from stid.fit.time_fit import fit_time
from stid.models.model import Model


def compare(runs, vehicle, models: list[str], method: str = "time", progress=None) -> list[dict]:
    models = [Model(name, vehicle) for name in models]  # names checked before any data work
    stretches = dataset.dynamic_stretches(runs)
    floor = noise_floor(stretches)
    entries = []
    for model in models:
        if progress:
            progress.step(model.name)
        res = fit_time(model, stretches) if method == "time" else fit_freq(model, stretches)
        ra = analyse(res.predictions)
        bd = breakdown(res.predictions)
        entries.append({
            "model": res.model, "method": res.method, "fit": res.fit, "aic": res.aic, "bic": res.bic,
            "params": {n: {"value": float(v), "stderr": float(se), "unit": res.units[n]}
                       for n, v, se in zip(res.names, res.values, res.stderr)},
            "noise_floor": floor, "white": {o: ra.white(o) for o in ("ay", "r")},
            "independent": {o: ra.independent(o) for o in ("ay", "r")},
            "by_band": bd.by_band, "by_ay": bd.by_ay, "by_run": bd.by_run, "warnings": res.warnings,
            "_result": res, "_resid": ra,
        })
    return entries
