"""Judge a fit on runs it was not fitted to (``--validate RUN``): the model at the
fitted parameters, driven by the held-out runs' steer at their speed, and the fit
percent it reaches there. A model that only fits its own data shows it here."""

from __future__ import annotations

import copy

from stid.fit.time_fit import _keep, fill_fit_stats, simulate
from stid.fit.result import Prediction


def judge_on(result, model, stretches, discard_s: float = 0.5):
    """A copy of ``result`` whose predictions and fit percent are those on ``stretches``
    (the parameters, intervals and information criteria stay the fit's)."""
    p = result.all_params()
    preds = []
    for st in stretches:
        k = _keep(st, discard_s)
        preds.append(Prediction(st.name, st.t, st.steer, st.y, simulate(model, p, st), st.vx, k))
    out = copy.copy(result)
    out.predictions = preds
    out.fit = {}
    fill_fit_stats(out, preds)
    out.loglik, out.n = result.loglik, result.n  # AIC/BIC stay those of the fit
    out.extra = dict(result.extra, validated_on=[st.name for st in stretches])
    return out
