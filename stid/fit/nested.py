"""A model that contains another starts from that model's solution.

``bicycle+X`` is ``bicycle`` when X sits at its zero (no lag, an infinite
friction limit, no offset), so its best fit can never be worse than the
bicycle's. A solve that starts at the catalogue's defaults can be: at a default
friction limit the model car may slide out on the runs' steering (the iterated
tyre force then does not settle, the cost is not smooth, and scipy stops after a
few evaluations where it began). The bicycle's solution is cheap (a linear
model) and puts the base parameters where the data want them; the effect's own
parameters start at their default or at their zero, whichever fits better (one
simulation each).

After the fit, the two are compared on the same samples: a model that ends
below the one it contains is refitted from the contained model's solution with
the effect at its zero, and if it still ends below, it says so and is not
called converged. A vehicle file whose [params] range keeps an effect off its
zero (``bounds_keep_off``) makes a model that no longer contains the bicycle:
it is not held to the bicycle's fit, and says why.
"""

from __future__ import annotations

import numpy as np

# log-likelihood units a containing model may end below the contained one before that is a
# failure: the effect's zero may lie just outside its bounds (mu up to 3, not infinity), which
# costs a fraction of a unit; a solve that failed costs hundreds
WORSE_LOGLIK = 2.0
BASE = "bicycle"


def effect_starts(model, inner: dict) -> dict:
    """Starting points of ``model`` around the contained model's parameters ``inner``, by what
    they are: its effects' parameters at their defaults, at their zeros (just inside the bounds;
    a log parameter cannot sit at 0), and the catalogue's defaults for everything."""
    default = model.defaults()
    at_default = dict(default, **{n: v for n, v in inner.items() if n in default})
    at_zero = dict(at_default)
    for e in model.effects:
        for q in e.params:
            if q.zero is not None:
                at_zero[q.name] = _reach(q, *model.bounds(q.name))
    return {"effects at default": at_default, "effects at zero": at_zero, "catalogue defaults": default}


def _reach(q, lo, hi) -> float:
    """How near its off value a parameter can sit within [lo, hi] (a log parameter above 0)."""
    return min(max(q.zero, lo * 1.5 if q.log else lo), hi)


def bounds_keep_off(model) -> list:
    """The effect parameters whose vehicle-file [params] range keeps them further from their off
    value than the catalogue's range does ("a servo lag of at least 30 ms"): with such a bound
    ``bicycle+X`` no longer contains the bicycle, and may fit worse than it."""
    v = model.vehicle
    return [q.name for e in model.effects for q in e.params if q.zero is not None
            and _reach(q, *model.bounds(q.name)) != _reach(q, q.catalogue("lower", v), q.catalogue("upper", v))]


def start_cost(model, p: dict, stretches, sigma, discard_s: float = 0.5) -> float:
    """The time-domain fit's cost at ``p``: the kept samples' residuals over ``sigma``, squared."""
    from stid.fit.time_fit import _keep, simulate

    total = 0.0
    for st in stretches:
        e = (simulate(model, p, st) - st.y)[_keep(st, discard_s)] / sigma
        total += float(np.sum(e ** 2))
    return total if np.isfinite(total) else float("inf")


def best_start(model, inner: dict, stretches) -> dict:
    """Of ``effect_starts``, the one that fits the stretches best."""
    sigma = np.std(np.vstack([s.y for s in stretches]), axis=0)
    sigma = np.where(sigma > 0, sigma, 1.0)
    return min(effect_starts(model, inner).values(), key=lambda p: start_cost(model, p, stretches, sigma))


def worse_than(result, inner) -> bool:
    """``result`` (a containing model) ends measurably below ``inner`` on the same samples."""
    return bool(np.isfinite(result.loglik) and np.isfinite(inner.loglik)
                and result.loglik < inner.loglik - WORSE_LOGLIK)


def say_worse(result, inner) -> None:
    """Mark ``result`` as failed: it fits worse than a model it contains."""
    fits = "   ".join(f"{o} {result.fit[o]:.1f}% vs {inner.fit[o]:.1f}%" for o in result.fit
                      if o in inner.fit and np.isfinite(result.fit[o]) and np.isfinite(inner.fit[o]))
    # (the likelihood decides: a trial user read "fits worse ... ay 99.6% vs 99.6%", fit percents that
    # round alike)
    why = (f"it fits worse than {inner.model}, which it contains (its log-likelihood {inner.loglik - result.loglik:.1f} "
           f"lower; {fits}), also when started from {inner.model}'s solution: the solver did not find its optimum")
    result.converged = False
    result.status = f"{result.status}; not an optimum: {why}" if result.status else f"not an optimum: {why}"
    result.undetermined = {n: "the fit did not converge" for n in result.names}
