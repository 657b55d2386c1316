"""Name the physical effect the model is missing.

For the current model M and each effect E of the catalogue not in it, fit M+E (by
the one fitting path every command uses, stid.fit.fitting.fit, so its numbers are
the ones ``stid fit --model M+E`` prints) and ask four questions:

1. Is the improvement more than chance? A likelihood-ratio test. Output-error
   residuals are coloured (the missing physics is filtered by the car), so the
   sample count is replaced by an effective one, N / tau, with tau the integrated
   autocorrelation time of M's residuals; the level is 1% with a Bonferroni
   correction over the candidates.
2. Does it matter? The effect must close at least a quarter of the gap between
   M's fit and the noise floor (what a correct model reaches on this data) and
   gain at least 0.5 fit points. A model already at the noise floor is missing
   nothing this data can show.
3. Is it one effect or the same symptom? Several effects can each close part of
   one residual. Only the best is a candidate to name; the others that pass 1-2 on
   their own are reported as the same symptom (``--peel`` tests them again once the
   best is added), or as not separable when chance could give the likelihood ratio
   between the two (``_indistinct``) and their signatures are known to coincide, with
   the run that would separate them.
4. Does the evidence hold (stid.analysis.evidence)? The best candidate is refitted
   at each speed (and amplitude) the runs hold; its parameter must be plausible
   (not at a bound) and one value within the intervals. If not, it is not named and
   the gap goes to ``unexplained`` with the reason. Before the ranking, sensor offsets
   must agree with the kinematics the data carry (stid.analysis.kinematics): a steering
   trim leaves the same mean residual, and the data, not the fit, decide which it is.

Candidates are ranked by the likelihood-ratio statistic. ``peel`` repeats the
round with the winner added until nothing is named.
"""

from __future__ import annotations

import math
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri  # chi-square survival function and its inverse (scipy.stats costs 0.4 s to import)

from stid import workers
from stid.analysis.evidence import Evidence, check_evidence
from stid.analysis.kinematics import kinematic_veto
from stid.analysis.noise_floor import noise_floor_uncertainty, submit_floor
from stid.analysis.residuals import analyse
from stid.analysis.unexplained import describe_unexplained
from stid.fit import dataset
from stid.fit.fitting import fit
from stid.models.effect import available_effects
from stid.models.model import Model, parse_model_name
from stid.models.params import unit_suffix

ALPHA = 0.01
MIN_GAIN = 0.5  # fit points
GAP_FRACTION = 0.25
OUTS = ("ay", "r")
WORKERS = workers.WORKERS


def p_in_words(p: float, level: float) -> str:
    """A p-value as a person reads it (the number stays in the JSON)."""
    if p < level * 1e-6:
        return "far beyond chance"
    if p < level:
        return f"beyond chance (odds of chance 1 in {1 / max(p, 1e-300):,.0f})"
    if p < 0.5:
        return "chance could give this"
    return "no better than chance"


@dataclass
class Candidate:
    effect: str
    result: object = None
    lr: float = 0.0
    p_value: float = 1.0
    level: float = ALPHA
    gain: dict = field(default_factory=dict)
    delta_bic: float = 0.0
    significant: bool = False
    passes: bool = False  # passes the chance and size tests on its own
    why_not: str = ""
    explanation: str = ""
    separable_from: dict = field(default_factory=dict)  # other effect -> advice
    same_symptom_as: str = ""
    evidence: object = None
    evidence_alone: object = None  # the first check, of the model with this effect alone (its per-speed fits)
    skipped: str = ""
    screen: dict = field(default_factory=dict)  # the linearised step's prediction (see screen_candidates)
    start: dict | None = None  # where the screen's step landed: a start for the full fit

    def p_words(self) -> str:
        return p_in_words(self.p_value, self.level)

    def own_params(self) -> dict:
        res = self.result
        return {n: float(v) for n, v in res.params().items() if res.owners.get(n) == self.effect}

    def to_json(self) -> dict:
        out = {"effect": self.effect, "significant": self.significant}
        if self.skipped:
            out["skipped"] = self.skipped
            return out
        if self.result is None:  # screened out by the linearised step: its prediction, not a fit
            out.update({"screened_out": self.why_not, "lr": round(self.lr, 1),
                        "p_value": float(f"{self.p_value:.3g}"), "chance": p_in_words(self.p_value, self.level),
                        "predicted_fit": {k: round(v, 2) for k, v in self.screen["fit"].items()}})
            return out
        res = self.result
        out.update({"fit": {k: round(v, 2) for k, v in res.fit.items()}, "delta_bic": round(self.delta_bic, 1),
                    "converged": res.converged,
                    "lr": round(self.lr, 1), "p_value": float(f"{self.p_value:.3g}"),
                    "chance": p_in_words(self.p_value, self.level),
                    "params": self.own_params(),
                    "intervals": {n: res.interval_of(n) for n in self.own_params()},
                    "units": {n: res.units.get(n, "") for n in self.own_params()},
                    "explanation": self.explanation})
        if self.evidence is not None:
            out["evidence"] = self.evidence.to_json()
        if not self.significant:
            out["why_not"] = self.why_not
        if self.same_symptom_as:
            out["same_symptom_as"] = self.same_symptom_as
        if self.separable_from:
            out["not_separable_from"] = self.separable_from
        return out


@dataclass
class Diagnosis:
    model: str
    base: object
    floor: dict
    tau: dict
    n_eff: float
    candidates: list
    floor_se: dict = field(default_factory=dict)
    unexplained: object = None  # stid.analysis.unexplained.Unexplained, on the last round
    stretches: list = None  # the data every fit of the diagnosis used (built once)

    @property
    def best(self):
        sig = [c for c in self.candidates if c.significant]
        return sig[0] if sig else None

    @property
    def same_symptom(self) -> list:
        """Candidates that pass on their own but explain the best one's residual."""
        return [c for c in self.candidates if c.same_symptom_as]

    def to_json(self) -> dict:
        res = self.base
        out = {"model": self.model, "fit": {k: round(v, 2) for k, v in res.fit.items()},
               "converged": res.converged, "status": res.status,
               "params": {n: d for n, d in res.params_json().items() if n in res.names},
               "noise_floor": {k: round(v, 2) for k, v in self.floor.items()},
               "noise_floor_stderr": {k: round(v, 3) for k, v in self.floor_se.items()},
               "effective_samples": round(self.n_eff),
               "candidates": [c.to_json() for c in self.candidates]}
        return out


def _lr(base, res, n_eff):
    """LR statistic with the effective sample size, outputs treated as independent."""
    eb = np.vstack([p.y[p.keep] - p.yhat[p.keep] for p in base.predictions])
    er = np.vstack([p.y[p.keep] - p.yhat[p.keep] for p in res.predictions])
    ratio = np.mean(eb ** 2, axis=0) / np.maximum(np.mean(er ** 2, axis=0), 1e-300)
    return float(n_eff * np.sum(np.log(ratio)))


def screen_out(effect_cls, stretches) -> str:
    """Why a candidate cannot be judged on this data (empty: it can)."""
    if effect_cls.name == "tyre_saturation":
        peak = max(np.max(np.abs(s.ay)) for s in stretches)
        if peak < 3.0:
            return (f"lateral acceleration never exceeds {peak:.1f} m/s^2 (0.3 g): the friction limit is "
                    "out of reach of this data; drive closer to the limit to test it")
    return ""


def diagnose_round(runs, vehicle, model_name: str = "bicycle", progress=None, base=None,
                   stretches=None, candidates=None, floor=None, pool=None) -> Diagnosis:
    """One round: every candidate effect against ``model_name``. ``floor``: the noise
    floor and its standard errors when the caller has them (or a Future of them);
    ``pool``: worker processes for the independent fits (``worker_pool``)."""
    stretches = stretches if stretches is not None else dataset.dynamic_stretches(runs)
    _, present = parse_model_name(model_name)
    if progress:
        progress.step(f"fitting {model_name}")
    base = base or fit(runs, vehicle, model_name, "time", stretches=stretches)
    ra = analyse(base.predictions)
    tau = max(ra.tau_int.values())
    n_eff = ra.n / tau
    if isinstance(floor, Future):  # computed in a worker while the base model was fitted
        floor = floor.result()
    floor, floor_se = floor if floor is not None else noise_floor_uncertainty(stretches)
    cands = []
    for name in [n for n in (candidates or available_effects()) if n not in present]:
        c = Candidate(name)
        c.skipped = screen_out(available_effects()[name], stretches)
        cands.append(c)
    todo = [c for c in cands if not c.skipped]
    level = ALPHA / max(len(todo), 1)
    if progress:
        progress.step(f"screening {len(todo)} effects")
    to_fit = screen_candidates(model_name, todo, vehicle, stretches, base, n_eff, level, pool)
    results = _fit_candidates(model_name, [c.effect for c in to_fit], vehicle, stretches, base.all_params(),
                              progress, pool, starts=[c.start for c in to_fit])
    for c, res in zip(to_fit, results):
        c.result = res
        k = len(available_effects()[c.effect].params)
        c.lr = max(_lr(base, res, n_eff), 0.0)
        c.p_value = float(chdtrc(k, c.lr))
        c.level = level
        c.gain = {o: res.fit[o] - base.fit[o] for o in OUTS}
        c.delta_bic = float(k * math.log(n_eff) - c.lr)
    todo = to_fit + [c for c in todo if c.result is None]
    # (a floor the data are too short to estimate is nan: then only MIN_GAIN decides)
    gap = {o: max(floor[o] - base.fit[o], 0.0) if np.isfinite(floor[o]) else 0.0 for o in OUTS}
    for c in to_fit:
        # it must gain at least MIN_GAIN points, and a quarter of the gap to the noise floor
        # where there is one (a nonlinear effect can beat the linear floor: then MIN_GAIN decides)
        need = {o: max(MIN_GAIN, GAP_FRACTION * gap[o]) for o in OUTS}
        enough = [o for o in OUTS if c.gain[o] >= need[o]]
        best_gain = max(c.gain.values())
        if not c.result.converged:  # where a solver stopped is no evidence either way
            c.why_not = "its fit did not converge: " + c.result.status.split("not an optimum: ")[-1]
        elif c.p_value >= level:
            c.why_not = f"not more than chance: {p_in_words(c.p_value, level)}"
        elif best_gain < MIN_GAIN:
            c.why_not = f"gains only {best_gain:.2f} fit points"
        elif not enough:
            c.why_not = (f"closes less than {100 * GAP_FRACTION:.0f}% of the gap to the noise floor "
                         f"(gains {', '.join(f'{o} {c.gain[o]:.2f}' for o in OUTS)})")
        else:
            c.passes = True
        if c.passes:  # a sensor offset the data's own kinematics rule out is no finding (a trim makes one)
            veto = kinematic_veto(c.effect, c.result, stretches)
            if veto:
                c.passes, c.evidence, c.why_not = False, Evidence(False, veto), f"not named: {veto}"
    todo.sort(key=lambda c: (not c.passes, -c.lr))
    _name_one(todo, model_name, vehicle, stretches, progress, pool, n_eff, floor)
    for c in todo:
        if c.result is not None:
            c.explanation = explain(c, base, stretches)
    ordered = todo + [c for c in cands if c.skipped]
    return Diagnosis(model_name, base, floor, ra.tau_int, n_eff, ordered, floor_se=floor_se)


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
        best_gain = max(c.gain.values())
        if c.p_value >= 100 * level:
            c.screen["why"] = "chance"
            c.why_not = (f"screened out: a linearised step from {model_name} is within chance "
                         f"({p_in_words(c.p_value, level)})")
        elif best_gain < 0.5 * MIN_GAIN:
            c.screen["why"] = "small"
            c.why_not = f"screened out: a linearised step from {model_name} gains only {best_gain:.2f} fit points"
        elif len(keep) >= MAX_FULL_FITS:
            c.screen["why"] = "capped"
            c.why_not = (f"screened out: {MAX_FULL_FITS} candidates gain more in a linearised step from "
                         f"{model_name} (this one: {best_gain:.1f} fit points)")
        else:
            keep.append(c)
    return keep + always


def linearised_steps(model_name, cands, vehicle, stretches, base, n_eff, level, pool=None):
    """The screen's step (see screen_candidates) for each candidate, from ``base``, a fit of
    ``model_name``: sets each one's ``lr``, ``p_value``, ``screen``, ``gain`` and ``start``.
    Returns (the candidates it cannot step: no off value, the stepped ones). The steps are
    independent: with a ``pool`` they are shared between the workers and this process."""
    always = [c for c in cands if not _offable(c.effect)]
    stepped = [c for c in cands if _offable(c.effect)]
    if not stepped:
        return always, stepped
    origin = _step_origin(model_name, vehicle, stretches, base)
    in_workers = all(_in_workers(f"{model_name}+{c.effect}") for c in stepped)
    # one share per core (not per process: a worker may still be busy with the noise floor)
    shares = _shares(stepped, WORKERS if pool is not None and in_workers else 1, cost=_step_cost)
    jobs = [(origin, [c.effect for c in share], n_eff, level) for share in shares]
    for share, found in zip(shares, _mapper(pool if in_workers else None, model_name)(_steps, jobs)):
        for c, values in zip(share, found):
            for k, v in values.items():
                setattr(c, k, v)
    return always, stepped


def _offable(effect: str) -> list:
    """The effect's parameters that have an off value (where the effect is absent)."""
    return [q for q in available_effects()[effect].params if q.zero is not None]


ITERATED_SIM_COST = 3  # a nonlinear effect's simulation is iterated: about three linear ones (measured)


def _step_cost(c) -> float:
    """A candidate's linearised step in simulations: one at the off value, one per parameter."""
    return (1 + len(_offable(c.effect))) * (ITERATED_SIM_COST if available_effects()[c.effect].iterated() else 1)


def _shares(items: list, n: int, cost) -> list:
    """``items`` in at most ``n`` shares of about equal ``cost``, each in the items' order
    (the largest first to the share that has least)."""
    shares = [[] for _ in range(min(n, len(items)))]
    load = [0.0] * len(shares)
    for i in sorted(range(len(items)), key=lambda i: -cost(items[i])):
        k = load.index(min(load))
        shares[k].append(i)
        load[k] += cost(items[i])
    return [[items[i] for i in sorted(share)] for share in shares]


@dataclass
class _StepOrigin:
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


def _step_origin(model_name, vehicle, stretches, base) -> _StepOrigin:
    sigma = np.asarray(base.extra.get("sigma", np.ones(2)), float)
    m0 = Model(model_name, vehicle)
    p0 = dict(base.all_params())
    r0 = _residuals(m0, p0, stretches, sigma)  # (n, 2)
    cols = []
    for n in base.names:
        lo, hi = m0.bounds(n)
        h = 1e-4 * (abs(p0[n]) if m0.param(n).log else (hi - lo))
        cols.append((_residuals(m0, dict(p0, **{n: p0[n] + h}), stretches, sigma) - r0) / h)
    return _StepOrigin(model_name, vehicle, stretches, p0, list(base.names), {o: base.fit[o] for o in OUTS},
                       sigma, r0, cols)


def _steps(args) -> list:
    """A share of the screen's steps (a worker's job): one dict of results per effect."""
    origin, effects, n_eff, level = args
    return [_step(origin, e, n_eff, level) for e in effects]


def _step(o: _StepOrigin, effect: str, n_eff: float, level: float) -> dict:
    """One candidate's linearised step from ``o`` (see screen_candidates)."""
    from scipy.optimize import lsq_linear

    def resid(model, p):
        return _residuals(model, p, o.stretches, o.sigma)

    cls = available_effects()[effect]
    offable = _offable(effect)
    m = Model(f"{o.model_name}+{effect}", o.vehicle)
    q0 = dict(o.p0, **{q.name: (q.zero if q.zero is not None else q.value("init", o.vehicle)) for q in cls.params})
    rq = resid(m, q0)
    J, lo_b, hi_b = list(o.cols), [-np.inf] * len(o.cols), [np.inf] * len(o.cols)
    moves = []  # (effect parameter, its off value, the change one unit of its coefficient makes)
    for q in offable:  # a coefficient on the change a small step away from the zero makes
        lo, hi = m.bounds(q.name)
        z = q0[q.name]
        if z > hi or z < lo - (hi - lo):  # an off value far outside the range (mu = 1e6): the secant
            h = (hi if z > hi else lo) - z  # to the nearest bound, scaled by c >= 0
            c_lo, c_hi = 0.0, np.inf
        else:
            d0 = q.value("init", o.vehicle)
            h = 0.01 * abs(d0) if d0 != 0 else 1e-3 * (hi - lo)
            c_lo, c_hi = (0.0, np.inf) if q.log else sorted(((lo - z) / h, (hi - z) / h))
        J.append(resid(m, dict(q0, **{q.name: z + h})) - rq)
        moves.append((q.name, z, h))
        lo_b.append(c_lo)
        hi_b.append(c_hi)
    A = np.stack([j.ravel() for j in J], axis=1)
    scale = np.maximum(np.linalg.norm(A, axis=0), 1e-300)  # columns of N/rad and metres alike
    step = lsq_linear(A / scale, -rq.ravel(), bounds=(np.array(lo_b) * scale, np.array(hi_b) * scale))
    r1 = (rq.ravel() + (A / scale) @ step.x).reshape(-1, 2)
    ratio = np.sum(rq ** 2, axis=0) / np.maximum(np.sum(r1 ** 2, axis=0), 1e-300)
    lr = max(float(n_eff * np.sum(np.log(ratio))), 0.0)
    screen = {"fit": {o_: 100.0 - (100.0 - o.fit_now[o_]) / np.sqrt(ratio[i]) for i, o_ in enumerate(OUTS)}}
    # where the step lands: a start for the full fit (often far closer than the effect at
    # its off value or at its default; the fit takes the best of the three)
    x = step.x / scale
    start = dict(q0, **{n: o.p0[n] + x[i] for i, n in enumerate(o.names)})
    start.update({name: z + x[len(o.cols) + j] * h for j, (name, z, h) in enumerate(moves)})
    start = {n: min(max(v, m.bounds(n)[0] * (1.5 if m.param(n).log else 1.0)), m.bounds(n)[1])
             for n, v in start.items() if n in m.param_names}
    return {"lr": lr, "p_value": float(chdtrc(len(offable), lr)), "level": level, "screen": screen,
            "start": start, "gain": {o_: screen["fit"][o_] - o.fit_now[o_] for o_ in OUTS}}


def _indistinct(top, c) -> bool:
    """Whether the data cannot tell candidate ``c`` from the winner ``top``.

    Both are fitted to the same data from the same base with the same effective sample
    size, so the difference of their likelihood-ratio statistics is twice the
    log-likelihood ratio of top against c, two non-nested models. They cannot be told
    apart when that difference is no more than chance gives one added parameter (or
    top's extra ones) at the candidates' level. A ratio of fit gains cannot say this: on
    a hidden sensor delay a servo lag gains 83% of what the delay gains (25.8 vs 31.0
    points) yet stays 3 points of r below the noise floor the delay reaches -- an LR
    difference of ~4960 against a critical 10.6."""
    extra = max(len(available_effects()[top.effect].params) - len(available_effects()[c.effect].params), 0)
    return top.lr - c.lr < chdtri(max(extra, 1), c.level)


def _name_one(ranked, model_name, vehicle, stretches, progress, pool=None, n_eff=None, floor=None) -> None:
    """Of the candidates that pass on their own, name at most one: the best, and only
    when its evidence holds. The others are the same symptom (or not separable).
    ``floor``: the noise floor per output, when known (see _ahead_of_the_rescue)."""
    passing = [c for c in ranked if c.passes]
    if not passing:
        return
    top = passing[0]
    for c in passing[1:]:
        advice = None
        if _indistinct(top, c):
            cls_top, cls_c = available_effects()[top.effect], available_effects()[c.effect]
            advice = cls_top.confused_with.get(c.effect) or cls_c.confused_with.get(top.effect)
        if advice:
            top.separable_from[c.effect] = advice
            c.separable_from[top.effect] = advice
            c.why_not = f"cannot be told apart from {top.effect} on this data: {advice}"
        else:
            c.same_symptom_as = top.effect
            c.why_not = f"the same symptom as {top.effect} (--peel tests it again once that is added)"
    # the partners of the rescue below: the other passing candidates, and those the screen passed
    # over only for want of room
    others = passing[1:] + [c for c in ranked if c.result is None and c.screen.get("why") == "capped"]
    ahead = _ahead_of_the_rescue(pool, model_name, top, others, vehicle, stretches, n_eff, floor)
    if progress:
        progress.step(f"checking {top.effect} at each speed")
    name = f"{model_name}+{top.effect}"
    # with the rescue's start in a worker the check's refits run here, one after the other: two
    # processes busy on two cores (beside it in the workers, the check and the start slow each other)
    top.evidence = top.evidence_alone = check_evidence(name, top.effect, vehicle, stretches, top.result,
                                                       map if ahead is not None else _mapper(pool, name))
    if not top.evidence.holds:
        # two effects missing at once: the second bends the first's parameter differently at
        # each speed. The first is still named if its value holds once one of the other
        # passing candidates is fitted with it (that one is then tested in the next round).
        first = None
        if ahead is not None and not ahead.cancel():
            order, first = ahead.result()
            partners = [next(o for o in others if o.effect == e) for e in order]
        else:
            partners = _rank_partners(model_name, top, others, vehicle, stretches, n_eff)
        partners = partners[:4]
        names = [f"{model_name}+{top.effect}+{o.effect}" for o in partners]
        # the joint fits are independent: they start in the workers one per core ahead of need,
        # and are read here in order, up to the first whose evidence holds (the same answer as
        # fitting them one after another; the likeliest partner is first, so usually one fit).
        # When the first was fitted ahead, the next starts only when needed: started now, it would
        # slow the first's check, which usually ends the rescue
        joint = _Ahead(pool if all(_in_workers(n2) for n2 in names) else None, _fit_joint,
                       _joint_jobs(model_name, top, partners, _alone(others), vehicle, stretches),
                       window=WORKERS if first is None else 1, known={0: first} if first is not None else None)
        for i, (other, name2) in enumerate(zip(partners, names)):
            if progress:
                progress.step(f"checking {top.effect} with {other.effect}")
            both = joint.result(i)
            k2 = len(available_effects()[other.effect].params)
            if n_eff is not None and chdtrc(k2, max(_lr(top.result, both, n_eff), 0.0)) >= top.level:
                # the partner adds nothing beyond chance to the first effect (it sits at or near
                # its off value): a joint fit that is the first effect alone is no second opinion
                continue
            ev = check_evidence(name2, top.effect, vehicle, stretches, both, _mapper(pool, name2))
            if ev.holds:
                ev.reason = f"holds once {other.effect} is fitted with it (first: {top.evidence.reason})"
                top.evidence = ev
                break
        joint.drop_the_rest()
    elif ahead is not None:
        ahead.cancel()  # (a running one is ended with the pool)
    if top.evidence.holds:
        top.significant = True
    else:
        top.why_not = f"not named: {top.evidence.reason}"


def _ahead_of_the_rescue(pool, model_name, top, others, vehicle, stretches, n_eff, floor):
    """The rescue's first step (the partners ranked, the joint fit with the likeliest),
    started in a worker beside the evidence check when the rescue is likely: the named effect
    leaves the data short of the noise floor by what a second effect could still be named for
    (MIN_GAIN). Where one effect is missing, the named one reaches the floor and nothing is
    started. A guess about timing only: whether the rescue runs is the check's answer.
    A Future of (partner effects in order, the first joint fit), or None."""
    if pool is None or not others or floor is None or n_eff is None:
        return None
    short = [o for o in OUTS if np.isfinite(floor[o]) and floor[o] - top.result.fit[o] >= MIN_GAIN]
    if not short or not all(_in_workers(f"{model_name}+{top.effect}+{o.effect}") for o in others):
        return None
    # the others travel light: their effects and parameters (the joint fits' starts), not their fits
    light = [Candidate(o.effect) for o in others]
    return pool.submit(_rescue_start, (model_name, top, light, _alone(others), vehicle, stretches, n_eff))


def _rescue_start(args):
    model_name, top, others, alone, vehicle, stretches, n_eff = args
    ranked = _rank_partners(model_name, top, others, vehicle, stretches, n_eff)
    (job,) = _joint_jobs(model_name, top, ranked[:1], alone, vehicle, stretches)
    return [o.effect for o in ranked], _fit_joint(job)


def _rank_partners(model_name, top, others, vehicle, stretches, n_eff) -> list:
    """The effects to fit jointly with ``top``, the likeliest second effect first: ranked by
    the screen's linearised step from the model with ``top`` added. Their own ranking was
    from the base model, where ``top``'s symptom dominated it (there, each effect that mimics
    a servo lag outranks an accelerometer offset that is really there)."""
    trial = [Candidate(o.effect) for o in others]
    unstepped, stepped = linearised_steps(f"{model_name}+{top.effect}", trial, vehicle, stretches, top.result,
                                          n_eff or 1.0, top.level)
    lr = {c.effect: c.lr for c in stepped}
    lr.update({c.effect: math.inf for c in unstepped})  # no off value to step from: fitted first
    return sorted(others, key=lambda o: -lr[o.effect])


def _alone(others) -> dict:
    """Effect -> the parameters of its fit alone (none for one the screen passed over)."""
    return {o.effect: o.result.all_params() if o.result is not None else {} for o in others}


def _joint_jobs(model_name, top, partners, alone: dict, vehicle, stretches) -> list:
    """The joint fits of ``top`` with each partner, started where each was fitted alone."""
    return [(f"{model_name}+{top.effect}+{o.effect}", vehicle, stretches, dict(alone[o.effect], **top.result.all_params()))
            for o in partners]


def _fit_joint(args):
    name, vehicle, stretches, init = args
    return fit((), vehicle, name, "time", stretches=stretches, init=init, multistart=False)


class _Ahead:
    """Jobs ``fn(job)`` started in the worker pool ahead of need (in ``order``), and read when
    needed. A job no worker has started when it is needed is done here instead of waited for.
    ``window``: at most that many jobs, from the one being read on, are started (for jobs read in
    order that may not all be needed: a worker busy with one that is not holds up what follows)."""

    def __init__(self, pool, fn, jobs, order=None, window=None, known=None):
        self.pool, self.fn, self.jobs = pool, fn, jobs
        self.order = list(range(len(jobs)) if order is None else order)
        self.window = len(jobs) if window is None else window
        self.futures = [None] * len(jobs)
        for i, result in (known or {}).items():  # done already, elsewhere
            self.futures[i] = Future()
            self.futures[i].set_result(result)
        self._submit_up_to(self.window)

    def _submit_up_to(self, n):
        if self.pool is not None:
            for i in self.order[:n]:
                if self.futures[i] is None:
                    self.futures[i] = self.pool.submit(self.fn, self.jobs[i])

    def result(self, i):
        self._submit_up_to(self.order.index(i) + self.window)
        f = self.futures[i]
        if f is None or f.cancel():
            return self.fn(self.jobs[i])
        return f.result()

    def drop_the_rest(self):
        """Those not needed: cancelled if not started (a running one is ended with the pool)."""
        for f in self.futures:
            if f is not None:
                f.cancel()


def _fit_one(args):
    model_name, effect, vehicle, stretches, init, screened = args
    m2 = Model(f"{model_name}+{effect}", vehicle)
    # start where the candidate equals the base model (its effect at zero) or at the effect's
    # default, whichever fits better: a candidate must never end worse than its base. Only the
    # start is chosen here; what is minimised is the fit path's, as `stid fit` has it.
    cls = available_effects()[effect]
    at_zero = {p.name: (p.zero if p.zero is not None else p.value("init", vehicle)) for p in cls.params}
    for p in cls.params:  # log parameters cannot sit at 0: just above it, inside the bounds
        lo, hi = m2.bounds(p.name)
        at_zero[p.name] = min(max(at_zero[p.name], lo * 1.5 if p.log else lo), hi)
    default = {p.name: p.value("init", vehicle) for p in cls.params}
    sigma = np.std(np.vstack([s.y for s in stretches]), axis=0)
    starts = [dict(init, **at_zero), dict(init, **default)] + ([dict(init, **screened)] if screened else [])
    best = min(starts, key=lambda q: _cost(m2, stretches, q, sigma))
    return fit((), vehicle, m2.name, "time", stretches=stretches, init=best, multistart=False)


def _residuals(model, p, stretches, sigma, discard_s=0.5) -> np.ndarray:
    """The time-domain fit's residuals (n, 2) over the kept samples of every stretch,
    each output divided by its ``sigma``: what the screen steps on and a start is judged by."""
    from stid.fit.time_fit import _keep, simulate

    return np.concatenate([(simulate(model, p, st) - st.y)[_keep(st, discard_s)] / sigma for st in stretches])


def _cost(model, stretches, p, sigma) -> float:
    return float(np.sum(_residuals(model, p, stretches, sigma) ** 2))


def worker_pool():
    """Worker processes for one diagnose (None on a one-core machine): the candidates'
    fits, the evidence's per-speed refits and the noise floor are independent, and run
    beside each other. Forked after the compiled simulator is loaded, so the workers
    share it instead of each loading it."""
    from stid.models.lpv import load_compiled

    return workers.worker_pool(WORKERS, before_fork=load_compiled)


def _in_workers(model_name: str) -> bool:
    """Effects defined in the user's own modules (a test file, a notebook) may not be
    importable in a worker process: models with one run in this process."""
    _, effects = parse_model_name(model_name)
    return all(available_effects()[e].__module__.startswith("stid.effects.") for e in effects)


def _mapper(pool, model_name: str):
    """A map over independent fits of ``model_name``: all but the last in the worker pool, the
    last here, where this process would otherwise only wait. With a worker still busy on a fit
    started ahead of need, two fits then run side by side, not one after the other on the
    free worker (a job the pool has queued counts as started: it cannot be taken back)."""
    if pool is None or not _in_workers(model_name):
        return map

    def here_and_there(fn, jobs):
        jobs = list(jobs)
        there = [pool.submit(fn, j) for j in jobs[:-1]]
        here = [fn(j) for j in jobs[-1:]]
        return [f.result() for f in there] + here

    return here_and_there


def _fit_candidates(model_name, effects, vehicle, stretches, init, progress=None, pool=None, starts=None):
    """Fit every candidate from the base's parameters (or where the screen's step landed,
    ``starts``, when that fits better), in the worker pool when there is one (each fit is
    independent)."""
    jobs = [(model_name, e, vehicle, stretches, init, s) for e, s in zip(effects, starts or [None] * len(effects))]
    if pool is None or len(jobs) < 2 or not all(_in_workers(f"{model_name}+{e}") for e in effects):
        out = []
        for j in jobs:
            if progress:
                progress.step(f"trying +{j[1]}")
            out.append(_fit_one(j))
        return out
    if progress:
        progress.step(f"trying {len(jobs)} effects on {WORKERS} cores")
    # the fits with most parameters first (each iteration costs a simulation per
    # parameter), so that the cores finish together; a fit no worker has taken yet is
    # done here rather than waited for
    order = sorted(range(len(jobs)), key=lambda i: -len(available_effects()[effects[i]].params))
    ahead = _Ahead(pool, _fit_one, jobs, order)
    out = {i: ahead.result(i) for i in reversed(order)}  # the last queued first: those are done here
    return [out[i] for i in range(len(jobs))]


def explain(c: Candidate, base, stretches) -> str:
    """One or two sentences with the numbers a vehicle engineer would check."""
    res = c.result
    p = res.params()
    speeds = sorted({round(s.vx, 1) for s in stretches})
    sp = ", ".join(f"{v:g}" for v in speeds) + " m/s"
    gain = ", ".join(f"{o} {base.fit[o]:.1f}% -> {res.fit[o]:.1f}%" for o in OUTS)
    cls = available_effects()[c.effect]
    at = f"at every speed ({sp})" if len(speeds) > 1 else f"at {sp} (one speed only)"
    if c.effect == "actuator_lag":
        lead = (f"yaw-rate and lateral-acceleration residuals follow the steer by ~{1000 * p['tau_steer']:.0f} ms "
                f"{at}: steering servo lag, tau = {1000 * p['tau_steer']:.0f} ms")
    elif c.effect == "tyre_relaxation":
        lags = ", ".join(f"{1000 * p['sigma_f'] / v:.0f} ms at {v:g} m/s" for v in speeds)
        lead = (f"the response lags more at low speed ({lags} at the front axle): tyre relaxation, "
                f"sigma_f = {p['sigma_f']:.3f} m, sigma_r = {p['sigma_r']:.3f} m")
    elif c.effect == "accel_offset":
        lead = (f"only the ay residual has structure, and it follows the yaw acceleration: the accelerometer "
                f"sits {100 * p['x_acc']:+.1f} cm {'ahead of' if p['x_acc'] > 0 else 'behind'} the CG")
    elif c.effect == "body_roll":
        lead = (f"ay reads {100 * 9.81 * p['roll_gain']:.1f}% high in steady cornering with a resonance near "
                f"{p['roll_freq']:.1f} Hz; yaw rate fits: the body rolls "
                f"{math.degrees(p['roll_gain']) * 9.81:.1f} deg/g and tilts the accelerometer")
    elif c.effect == "tyre_saturation":
        lead = (f"the fit is good at low |ay| and fails toward the peaks: the tyres saturate, mu = {p['mu']:.2f} "
                f"(friction limit {9.81 * p['mu']:.1f} m/s^2)")
    elif c.effect == "sensor_bias":
        lead = (f"the residuals have a constant part unrelated to steer: gyro offset "
                f"{math.degrees(p['bias_r']):+.2f} deg/s, accelerometer offset {p['bias_ay']:+.3f} m/s^2 "
                "left after calibration")
    else:
        ps = ", ".join(f"{n} = {v:.4g}{unit_suffix(res.units.get(n, ''))}" for n, v in c.own_params().items())
        lead = f"{cls.signature}: {c.effect} ({ps})" if cls.signature else f"{c.effect} ({ps})"
    text = f"{lead}. Adding it: {gain}."
    if c.separable_from:
        other, advice = next(iter(c.separable_from.items()))
        text += f" Cannot be told apart from {other} on this data: {advice}."
    return text


def diagnose(runs, vehicle, model_name: str = "bicycle", peel: bool = False, max_steps: int = 4,
             progress=None, candidates=None) -> list[Diagnosis]:
    """One round, or (peel) rounds adding the winner until nothing is named. The last
    round carries ``unexplained``: what remains, and where.
    ``candidates``: effect names to try (default: every registered effect)."""
    Model(model_name, vehicle)  # a misspelt model is the user's first mistake to hear about
    stretches = dataset.dynamic_stretches(runs)  # built once: every fit of every round uses them
    with worker_pool() as pool:
        floor = submit_floor(pool, stretches) if pool else noise_floor_uncertainty(stretches)
        rounds = []
        name = model_name
        base = None
        for _ in range(max_steps if peel else 1):
            d = diagnose_round(runs, vehicle, name, progress=progress, base=base, stretches=stretches,
                               candidates=candidates, floor=floor, pool=pool)
            floor = (d.floor, d.floor_se)
            d.stretches = stretches
            rounds.append(d)
            best = d.best
            if best is None or best.separable_from:
                break
            name = f"{name}+{best.effect}"
            base = best.result
        last = rounds[-1]
        if progress:
            progress.step("looking where the error remains")
        named = last.best
        final_name, final = (f"{last.model}+{named.effect}", named.result) if named else (last.model, last.base)
        reasons = [f"{c.effect} is {c.why_not}" for c in last.candidates
                   if c.evidence is not None and not c.evidence.holds]
        # the final model's per-speed fits were made when its last effect's evidence was checked
        # (the same model, data and start): read there, not fitted again
        checked = named or (rounds[-2].best if len(rounds) > 1 else None)
        parts = checked.evidence_alone.partitions if checked and checked.evidence_alone else None
        last.unexplained = describe_unexplained(final_name, final, vehicle, stretches, floor[0], floor[1], reasons,
                                                catalogue_done=named is None, mapper=_mapper(pool, final_name),
                                                parts=parts)
    return rounds
