"""The screen: which candidate effects are worth a full fit.

A score test (Lagrange multiplier) per candidate: at the current model's fit, the
candidate with its effect switched off is the same model, so one Gauss-Newton step from
there predicts how far the candidate can lower the cost, in a few simulations instead of
a fit. The diagnosis screens the candidates from its base model, and the partners of a
candidate whose evidence fails from that candidate's fit (stid.search.pairs)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc  # chi-square survival function

from stid.models.effect import available_effects
from stid.models.model import Model
from stid.search.candidate import MIN_GAIN, OUTS
from stid.search.pool import WORKERS, in_workers, mapper, shares

MAX_FULL_FITS = 4  # candidates the screen passes on to a full fit, best first


def screen_candidates(model_name, cands, vehicle, stretches, base, n_eff, level, pool=None) -> list:
    """The candidates worth a full fit, best first; the others get the screen's verdict.

    A score test (Lagrange multiplier): at the current model's fit, the candidate with
    its effect switched off is the same model. One Gauss-Newton step from there, with the
    effect's parameters held to their physical side (a lag is not negative) and the
    model's own parameters free, predicts how far the candidate can lower the cost: a
    few simulations per candidate instead of a fit. A candidate passes to the full fit
    unless that step is within chance by a wide margin or predicts less than half the
    gain the naming rule needs; at most MAX_FULL_FITS of them, best first. A parameter
    whose off value lies far outside its range (a friction coefficient of 1e6) is stepped
    to its nearest bound instead (the secant, scaled by a coefficient >= 0). An effect
    with no off value cannot be screened and is always fitted."""
    always, screened = linearised_steps(model_name, cands, vehicle, stretches, base, n_eff, level, pool)
    screened.sort(key=lambda c: -c.lr)
    keep = []
    for c in screened:
        if not sift(c, model_name, level):
            continue
        if len(keep) >= MAX_FULL_FITS:
            c.screen["why"] = "capped"
            c.why_not = (f"screened out: {MAX_FULL_FITS} candidates gain more in a linearised step from "
                         f"{model_name} (this one: {max(c.gain.values()):.1f} fit points)")
        else:
            keep.append(c)
    return keep + always


def sift(c, model_name, level) -> bool:
    """Whether a stepped candidate passes the screen: not when its step from ``model_name``
    is within chance by a wide margin (100 times the level) or gains less than half of what
    the naming rule needs; then its ``why_not`` and ``screen["why"]`` say which."""
    best_gain = max(c.gain.values())
    if c.p_value >= 100 * level:
        c.screen["why"] = "chance"
        c.why_not = (f"screened out: a linearised step from {model_name} is within chance "
                     f"(p = {c.p_value:.2g})")
        return False
    if best_gain < 0.5 * MIN_GAIN:
        c.screen["why"] = "small"
        c.why_not = f"screened out: a linearised step from {model_name} gains only {best_gain:.2f} fit points"
        return False
    return True


def linearised_steps(model_name, cands, vehicle, stretches, base, n_eff, level, pool=None):
    """The screen's step (see screen_candidates) for each candidate, from ``base``, a fit of
    ``model_name``: sets each one's ``lr``, ``p_value``, ``screen``, ``gain`` and ``start``.
    Returns (the candidates it cannot step: no off value, the stepped ones). The steps are
    independent: with a ``pool`` they are shared between the workers and this process."""
    always = [c for c in cands if not offable(c.effect)]
    stepped = [c for c in cands if offable(c.effect)]
    if not stepped:
        return always, stepped
    origin = step_origin(model_name, vehicle, stretches, base)
    there = all(in_workers(f"{model_name}+{c.effect}") for c in stepped)
    # one share per core (not per process: a worker may still be busy with the noise floor)
    split = shares(stepped, WORKERS if pool is not None and there else 1, cost=step_cost)
    jobs = [(origin, [c.effect for c in share], n_eff, level) for share in split]
    for share, found in zip(split, mapper(pool if there else None, model_name)(_steps, jobs)):
        for c, values in zip(share, found):
            for k, v in values.items():
                setattr(c, k, v)
    return always, stepped


def offable(effect: str) -> list:
    """The effect's parameters that have an off value (where the effect is absent)."""
    return [q for q in available_effects()[effect].params if q.zero is not None]


ITERATED_SIM_COST = 3  # a nonlinear effect's simulation is iterated: about three linear ones (measured)


def step_cost(c) -> float:
    """A candidate's linearised step in simulations: one at the off value, one per parameter."""
    return (1 + len(offable(c.effect))) * (ITERATED_SIM_COST if available_effects()[c.effect].iterated() else 1)


@dataclass
class StepOrigin:
    """Where every candidate's linearised step starts: the current model's fit, its weighted
    residuals and their change with each of its own parameters (shared by every candidate)."""
    model_name: str
    vehicle: object
    stretches: list
    p0: dict
    names: list
    fit_now: dict
    sigma: np.ndarray
    r0: np.ndarray
    cols: list
    own_ss: np.ndarray = None  # each output's sum of squares after the step in the model's own parameters alone

    def own_gain(self) -> float:
        """Fit points the model's own parameters gain in one linearised step from its fit (~0 at an optimum
        where the model is near linear)."""
        if self.own_ss is None:
            return 0.0
        ratio = np.sum(self.r0 ** 2, axis=0) / np.maximum(self.own_ss, 1e-300)
        return float(max((100.0 - self.fit_now[o]) * (1 - 1 / np.sqrt(max(ratio[i], 1.0))) for i, o in enumerate(OUTS)))


def step_origin(model_name, vehicle, stretches, base) -> StepOrigin:
    sigma = np.asarray(base.extra.get("sigma", np.ones(2)), float)
    m0 = Model(model_name, vehicle)
    p0 = dict(base.all_params())
    steps = []
    for n in base.names:
        lo, hi = m0.bounds(n)
        steps.append(1e-4 * (abs(p0[n]) if m0.param(n).log else (hi - lo)))
    r0, *moved = residuals_many(m0, [p0] + [dict(p0, **{n: p0[n] + h}) for n, h in zip(base.names, steps)],
                                stretches, sigma)  # (n, 2) each
    cols = [(r - r0) / h for r, h in zip(moved, steps)]
    # what the model's own parameters gain in the same linearised step, without any candidate: at an
    # optimum nothing; where the linearisation is poor (a fit of bicycle+tyre_relaxation to a car with
    # a servo lag), as much as 4.6 fit points, which every candidate's step then predicted alike, and
    # the ranking among them was by what was left (the lag was not fitted, a locked_diff was named)
    if cols:
        A = np.stack([c.ravel() for c in cols], axis=1)
        x, *_ = np.linalg.lstsq(A, -r0.ravel(), rcond=None)
        own = (r0.ravel() + A @ x).reshape(-1, 2)
    else:
        own = r0
    return StepOrigin(model_name, vehicle, stretches, p0, list(base.names), {o: base.fit[o] for o in OUTS},
                       sigma, r0, cols, np.sum(own ** 2, axis=0))


def _steps(args) -> list:
    """A share of the screen's steps (a worker's job): one dict of results per effect."""
    origin, effects, n_eff, level = args
    return [_step(origin, e, n_eff, level) for e in effects]


def _step(o: StepOrigin, effect: str, n_eff: float, level: float) -> dict:
    """One candidate's linearised step from ``o`` (see screen_candidates)."""
    from scipy.optimize import lsq_linear

    cls = available_effects()[effect]
    off = offable(effect)
    m = Model(f"{o.model_name}+{effect}", o.vehicle)
    q0 = dict(o.p0, **{q.name: (q.zero if q.zero is not None else q.value("init", o.vehicle)) for q in cls.params})
    J, lo_b, hi_b = list(o.cols), [-np.inf] * len(o.cols), [np.inf] * len(o.cols)
    moves = []  # (effect parameter, its off value, the change one unit of its coefficient makes)
    for q in off:  # a coefficient on the change a small step away from the zero makes
        lo, hi = m.bounds(q.name)
        z = q0[q.name]
        if z > hi or z < lo - (hi - lo):  # an off value far outside the range (mu = 1e6): the secant
            h = (hi if z > hi else lo) - z  # to the nearest bound, scaled by c >= 0
            c_lo, c_hi = 0.0, np.inf
        else:
            d0 = q.value("init", o.vehicle)
            h = 0.01 * abs(d0) if d0 != 0 else 1e-3 * (hi - lo)
            c_lo, c_hi = (0.0, np.inf) if q.log else sorted(((lo - z) / h, (hi - z) / h))
        moves.append((q.name, z, h))
        lo_b.append(c_lo)
        hi_b.append(c_hi)
    rq, *moved = residuals_many(m, [q0] + [dict(q0, **{name: z + h}) for name, z, h in moves], o.stretches, o.sigma)
    J += [r - rq for r in moved]
    A = np.stack([j.ravel() for j in J], axis=1)
    scale = np.maximum(np.linalg.norm(A, axis=0), 1e-300)  # columns of N/rad and metres alike
    step = lsq_linear(A / scale, -rq.ravel(), bounds=(np.array(lo_b) * scale, np.array(hi_b) * scale))
    r1 = (rq.ravel() + (A / scale) @ step.x).reshape(-1, 2)
    # (against the model's own step: the candidate's share of the gain, as a score test measures it)
    ratio = np.maximum(o.own_ss if o.own_ss is not None else np.sum(rq ** 2, axis=0), 1e-300) / \
        np.maximum(np.sum(r1 ** 2, axis=0), 1e-300)
    ratio = np.maximum(ratio, 1.0)
    lr = max(float(n_eff * np.sum(np.log(ratio))), 0.0)
    screen = {"fit": {o_: 100.0 - (100.0 - o.fit_now[o_]) / np.sqrt(ratio[i]) for i, o_ in enumerate(OUTS)},
              "own_gain": o.own_gain()}
    # where the step lands: a start for the full fit (often far closer than the effect at
    # its off value or at its default; the fit takes the best of the three)
    x = step.x / scale
    start = dict(q0, **{n: o.p0[n] + x[i] for i, n in enumerate(o.names)})
    start.update({name: z + x[len(o.cols) + j] * h for j, (name, z, h) in enumerate(moves)})
    start = {n: min(max(v, m.bounds(n)[0] * (1.5 if m.param(n).log else 1.0)), m.bounds(n)[1])
             for n, v in start.items() if n in m.param_names}
    return {"lr": lr, "p_value": float(chdtrc(len(off), lr)), "level": level, "screen": screen,
            "start": start, "gain": {o_: screen["fit"][o_] - o.fit_now[o_] for o_ in OUTS}}


def residuals(model, p, stretches, sigma, discard_s=0.5) -> np.ndarray:
    """The time-domain fit's residuals (n, 2) over the kept samples of every stretch,
    each output divided by its ``sigma``: what the screen steps on and a start is judged by."""
    return residuals_many(model, [p], stretches, sigma, discard_s)[0]


def residuals_many(model, ps: list, stretches, sigma, discard_s=0.5) -> list:
    """``[residuals(model, p, stretches, sigma) for p in ps]``, each stretch's simulations in one
    batch where the model can (Model.simulate_many; one parameter set: Model.simulate)."""
    from stid.fit.time_fit import _keep, simulate_many

    per_stretch = [[(y - st.y)[_keep(st, discard_s)] / sigma for y in simulate_many(model, ps, st)]
                   for st in stretches]
    return [np.concatenate(rs) for rs in zip(*per_stretch)]


def cost(model, stretches, p, sigma) -> float:
    return float(np.sum(residuals(model, p, stretches, sigma) ** 2))
