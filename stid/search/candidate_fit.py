"""The full fit of a candidate model (the base model with one effect more), from the best
of a few starts, by the one fitting path every command uses (stid.fit.fitting.fit), so its
numbers are the ones ``stid fit --model M+E`` prints."""

from __future__ import annotations

import numpy as np

from stid.fit.fitting import fit
from stid.models.effect import available_effects
from stid.models.model import Model
from stid.search.pool import WORKERS, in_workers, shared
from stid.search.screen import cost


def fit_candidate(args):
    """``(model_name, effect, vehicle, stretches, init, screened[, more])``: ``model_name``
    with ``effect`` added, fitted from ``init`` (the base's parameters) with the effect at
    its off value, at its default, where the screen's step landed (``screened``) or at its
    values in each of ``more`` (other fits' parameters), whichever fits best. At its off value the
    candidate is the base model, so it never ends worse than its base. Only the start is
    chosen here; what is minimised is the fit path's, as `stid fit` has it."""
    model_name, effect, vehicle, stretches, init, screened, *more = args
    m2 = Model(f"{model_name}+{effect}", vehicle)
    cls = available_effects()[effect]
    at_zero = {p.name: (p.zero if p.zero is not None else p.value("init", vehicle)) for p in cls.params}
    for p in cls.params:  # log parameters cannot sit at 0: just above it, inside the bounds
        lo, hi = m2.bounds(p.name)
        at_zero[p.name] = min(max(at_zero[p.name], lo * 1.5 if p.log else lo), hi)
    default = {p.name: p.value("init", vehicle) for p in cls.params}
    sigma = np.std(np.vstack([s.y for s in stretches]), axis=0)
    starts = [dict(init, **at_zero), dict(init, **default)] + ([dict(init, **screened)] if screened else [])
    own = {p.name for p in cls.params}  # from another fit (the effect's alone), only the effect's own values
    starts += [dict(init, **{n: s[n] for n in own}) for s in (more[0] if more else ()) if own <= set(s)]
    best = min(starts, key=lambda q: cost(m2, stretches, q, sigma))
    return fit((), vehicle, m2.name, "time", stretches=stretches, init=best, multistart=False)


def fit_candidates(model_name, effects, vehicle, stretches, init, progress=None, pool=None, starts=None):
    """Fit every candidate from the base's parameters (or where the screen's step landed,
    ``starts``, when that fits better), in the worker pool when there is one (each fit is
    independent)."""
    jobs = [(model_name, e, vehicle, stretches, init, s) for e, s in zip(effects, starts or [None] * len(effects))]
    if pool is None or len(jobs) < 2 or not all(in_workers(f"{model_name}+{e}") for e in effects):
        out = []
        for j in jobs:
            if progress:
                progress.step(f"trying +{j[1]}")
            out.append(fit_candidate(j))
        return out
    if progress:
        progress.step(f"trying {len(jobs)} effects on {WORKERS} cores")
    # the fits with most parameters first (each iteration costs a simulation per
    # parameter), so that the cores finish together; a fit no worker has taken yet is
    # done here rather than waited for
    order = sorted(range(len(jobs)), key=lambda i: -len(available_effects()[effects[i]].params))
    return shared(pool, fit_candidate, jobs, order)
