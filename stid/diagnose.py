"""Name the physical effect the model is missing.

For the current model M and each effect E of the catalogue not in it, fit M+E (by
the one fitting path every command uses, stid.fit.fitting.fit, so its numbers are
the ones ``stid fit --model M+E`` prints) and ask four questions:

1. Is the improvement more than chance? A likelihood-ratio test. Output-error
   residuals are coloured (the missing physics is filtered by the car), so the
   sample count is replaced by an effective one, N / tau, with tau the integrated
   autocorrelation time of M's residuals; the level is 1% with a Bonferroni
   correction over the candidates.
2. Does it matter, and do the data show it? The effect must close at least a quarter
   of the gap between M's fit and the noise floor (what a correct model reaches on this
   data) and gain at least 0.5 fit points; and not every parameter of it may have a 95%
   interval that holds its off value. A model already at the noise floor is missing
   nothing this data can show; a model above it (the floor misses a nonlinearity the data
   hold, such as tyres deep in saturation) leaves the gap rule no reference, and a name
   then needs runs at two steer amplitudes, across which its evidence must hold.
3. Is it one effect or the same symptom? Several effects can each close part of
   one residual. Only the best is a candidate to name; the others that pass 1-2 on
   their own are reported as the same symptom (``--peel`` tests them again once the
   best is added), or as not separable when chance could give the likelihood ratio
   between the two (``_indistinct``) and their signatures are known to coincide, with
   the run that would separate them.
4. Does the evidence hold (stid.analysis.evidence)? The best candidate is refitted
   at each speed (and amplitude) the runs hold; its parameter must be plausible
   (not at a bound) and one value within the intervals. If not, a second missing
   effect may be bending it: it is fitted jointly with each other effect of the
   catalogue (stid.search.pairs), and the pair is named when both hold. If no pair
   holds, nothing is named and the gap goes to ``unexplained`` with the reason and
   the pairs tried. Before the ranking, sensor offsets must agree with the kinematics
   the data carry (stid.analysis.kinematics): a steering trim leaves the same mean
   residual, and the data, not the fit, decide which it is.

Candidates are ranked by the likelihood-ratio statistic. ``peel`` repeats the
round with the winner (or the pair) added until nothing is named. The search's pieces
(the screen, the candidates' fits, the pairs, the explanations, the worker pool) are in
stid.search; this module holds the rules of one round and the rounds.
"""

from __future__ import annotations

import math
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc  # chi-square survival function (scipy.stats costs 0.4 s to import)

from stid.analysis.evidence import Evidence, check_evidence, partitions
from stid.analysis.kinematics import kinematic_veto
from stid.analysis.noise_floor import above_floor, noise_floor_uncertainty, submit_floor
from stid.analysis.residuals import analyse
from stid.analysis.unexplained import describe_unexplained
from stid.fit import dataset
from stid.fit.fitting import fit
from stid.models.effect import available_effects
from stid.models.model import Model, parse_model_name
from stid.search.candidate import ALPHA, GAP_FRACTION, MIN_GAIN, OUTS, Candidate, indistinct, lr_statistic, \
    p_in_words
from stid.search.candidate_fit import fit_candidates
from stid.search.explain import explain
from stid.search.pairs import search_pairs, start_ahead
from stid.search.pool import mapper, worker_pool
from stid.search.screen import screen_candidates

__all__ = ["ALPHA", "Candidate", "Diagnosis", "diagnose", "diagnose_round"]


def screen_out(effect_cls, stretches) -> str:
    """Why a candidate cannot be judged on this data (empty: it can)."""
    if effect_cls.name == "tyre_saturation":
        peak = max(np.max(np.abs(s.ay)) for s in stretches)
        if peak < 3.0:
            return (f"lateral acceleration never exceeds {peak:.1f} m/s^2 (0.3 g): the friction limit is "
                    "out of reach of this data; drive closer to the limit to test it")
    return ""


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
    def named(self) -> list:
        """The effects this round tells the user to add: the best, or the pair it is named in."""
        best = self.best
        return [] if best is None else [best.effect] + ([best.pair_with] if best.pair_with else [])

    @property
    def named_model(self) -> str:
        return "+".join([self.model, *self.named])

    @property
    def named_result(self):
        """The fit of ``named_model``: the pair's joint fit, the best's, or the base's."""
        best = self.best
        if best is None:
            return self.base
        return best.pairs.named.result if best.pair_with else best.result

    @property
    def named_parts(self):
        """The per-speed fits of ``named_model`` made by its evidence check, or None."""
        best = self.best
        if best is None:
            return None
        ev = best.evidence if best.pair_with else best.evidence_alone
        return ev.partitions if ev is not None else None

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
               # fit points above the floor, per output where beyond chance: then nothing more is named
               "above_floor": above_floor(res.fit, self.floor, self.floor_se), **res._delay_json(),
               "effective_samples": round(self.n_eff),
               "named": self.named,
               "candidates": [c.to_json() for c in self.candidates]}
        return out


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
    results = fit_candidates(model_name, [c.effect for c in to_fit], vehicle, stretches, base.all_params(),
                             progress, pool, starts=[c.start for c in to_fit])
    for c, res in zip(to_fit, results):
        c.result = res
        k = len(available_effects()[c.effect].params)
        c.lr = max(lr_statistic(base, res, n_eff), 0.0)
        c.p_value = float(chdtrc(k, c.lr))
        c.level = level
        c.gain = {o: res.fit[o] - base.fit[o] for o in OUTS}
        c.delta_bic = float(k * math.log(n_eff) - c.lr)
    todo = to_fit + [c for c in todo if c.result is None]
    # (a floor the data are too short to estimate is nan: then only MIN_GAIN decides)
    gap = {o: max(floor[o] - base.fit[o], 0.0) if np.isfinite(floor[o]) else 0.0 for o in OUTS}
    # A model above the noise floor leaves the floor no reference: any gain then passes the gap rule,
    # and a new user's simulated cars with saturating tyres (a magic-formula law, not the catalogue's
    # tanh) had a locked_diff named for 0.6 fit points in 5 of 7 pairs. A name there needs runs at two
    # steer amplitudes, across which the evidence check then holds its parameter to one value.
    above = above_floor(base.fit, floor, floor_se)
    amplitudes = bool(above) and "amplitude" in partitions(stretches)  # (asked only where it decides)
    for c in to_fit:
        # it must gain at least MIN_GAIN points, and a quarter of the gap to the noise floor
        # where there is one (a nonlinear effect can beat the linear floor: then MIN_GAIN decides)
        need = {o: max(MIN_GAIN, GAP_FRACTION * gap[o]) for o in OUTS}
        enough = [o for o in OUTS if c.gain[o] >= need[o]]
        best_gain = max(c.gain.values())
        if not c.result.converged:  # where a solver stopped is no evidence either way
            c.why_not = "its fit did not converge: " + c.result.status.split("not an optimum: ")[-1]
        elif c.p_value >= level:
            c.why_not = p_in_words(c.p_value, level)  # ("chance could give this", "no better than chance")
        elif best_gain < MIN_GAIN:
            c.why_not = f"gains only {best_gain:.2f} fit points"
        elif not enough:
            c.why_not = (f"closes less than {100 * GAP_FRACTION:.0f}% of the gap to the noise floor "
                         f"(gains {', '.join(f'{o} {c.gain[o]:.2f}' for o in OUTS)})")
        else:
            c.passes = True
        absent = _interval_holds_absence(c)
        if c.passes and absent:
            c.passes, c.why_not = False, f"its own 95% interval holds the effect's absence ({absent}): not shown"
        if c.passes and above and not amplitudes:
            c.passes, c.why_not = False, (
                f"not named: {model_name} fits above the noise floor, which is then no reference for what is "
                f"left, and the runs hold one steer amplitude: its gain ({', '.join(f'{o} {c.gain[o]:+.1f}' for o in OUTS)} "
                "points) may stand in for what the floor misses, such as a tyre law other than the catalogue's "
                "tanh; runs at a second steer amplitude (half or twice this one) test it: an effect of the car "
                "keeps its value there")
        if c.passes:  # a sensor offset the data's own kinematics rule out is no finding (a trim makes one)
            veto = kinematic_veto(c.effect, c.result, stretches)
            if veto:
                c.passes, c.evidence, c.why_not = False, Evidence(False, veto), f"not named: {veto}"
    todo.sort(key=lambda c: (not c.passes, -c.lr))
    skipped = [c for c in cands if c.skipped]
    _name_one(todo, skipped, model_name, vehicle, stretches, progress, pool, n_eff, floor)
    top = next((c for c in todo if c.significant), None)
    if top is not None and top.pair_with:  # the partner follows the first, and is explained against it
        partner = next(c for c in todo if c.effect == top.pair_with)
        todo.remove(partner)
        todo.insert(todo.index(top) + 1, partner)
    for c in todo:
        if c.result is None:
            continue
        if c.pair_with and c is top:  # its numbers are the pair's: alone, the second bent them
            c.explanation = explain(c, base, stretches, c.pairs.named.result, f"Adding it with {c.pair_with}")
        elif c.pair_with:
            c.explanation = explain(c, top.result, stretches, adding=f"Adding it to {model_name}+{top.effect}")
        else:
            c.explanation = explain(c, base, stretches)
    return Diagnosis(model_name, base, floor, ra.tau_int, n_eff, todo + skipped, floor_se=floor_se,
                     stretches=stretches)


def _interval_holds_absence(c) -> str:
    """Where every parameter of the effect that has an off value (where the effect is absent) has
    a 95% interval that holds it, the words that say so; empty otherwise. The likelihood ratio's
    N / tau samples count model error as signal; the intervals (jackknife, geometry) do not, and
    the two disagreed: a locked_diff named 'far beyond chance' with k_diff 3.3 [-0.43, 7.0] N m."""
    from stid.fit.result import at_resolution

    words = []
    for q in available_effects()[c.effect].params:
        if q.zero is None or not math.isfinite(q.zero):
            continue
        ci = c.result.interval_of(q.name)
        if ci is None or not ci[0] <= q.zero <= ci[1]:
            return ""
        se = dict(zip(c.result.names, c.result.stderr)).get(q.name, float("nan"))
        words.append(f"{q.name} [{at_resolution(ci[0], se)}, {at_resolution(ci[1], se)}] holds {q.zero:g}")
    return "; ".join(words)


def _name_one(ranked, skipped, model_name, vehicle, stretches, progress, pool=None, n_eff=None,
              floor=None) -> None:
    """Of the candidates that pass on their own, name at most one: the best whose evidence holds,
    alone or fitted jointly with a second effect (then the pair, when the second's holds too). The
    others are the same symptom as the one named (or not separable from it). ``skipped``: the
    candidates this data cannot test (a pair with them is not tried, and that is said);
    ``floor``: the noise floor per output, when known.

    The best by likelihood ratio is checked first, with the pair search where its evidence fails.
    Where no pair holds either, a candidate the data cannot tell from it by the fit (``indistinct``)
    is checked on its own evidence, and named where that holds: the fit cannot choose between the
    two, and the evidence can (a servo lag and a sensor delay on slow steering, one of them bent by
    something else)."""
    passing = [c for c in ranked if c.passes]
    if not passing:
        return
    top = passing[0]
    _same_symptom(top, passing[1:])
    # every other effect the data can test is a partner: the screen from the base model, where the
    # first's symptom filled the residual, cannot rule one out (the search screens them again)
    others = [c for c in ranked if c is not top] + skipped
    ahead = start_ahead(pool, model_name, top, others, vehicle, stretches, n_eff, floor)
    if progress:
        progress.step(f"checking {top.effect} at each speed")
    name = f"{model_name}+{top.effect}"
    # with the search's start in a worker the check's refits run here, one after the other: two
    # processes busy on two cores (beside it in the workers, the check and the start slow each other)
    top.evidence = top.evidence_alone = check_evidence(name, top.effect, vehicle, stretches, top.result,
                                                       map if ahead is not None else mapper(pool, name))
    if top.evidence.holds:
        if ahead is not None:
            ahead.cancel()  # (a running one is ended with the pool)
        top.significant = True
        return
    top.pairs = search_pairs(model_name, top, others, vehicle, stretches, n_eff, floor, pool, ahead, progress)
    held = top.pairs.holds_with  # (a pair is named when both hold: see stid.search.pairs.holds_with)
    if held is not None:
        held.evidence.reason = f"holds once {held.partner} is fitted with it (first: {top.evidence.reason})"
        top.evidence = held.evidence
        top.significant = True
        _name_partner(top, next(c for c in ranked if c.effect == held.partner), held, n_eff)
        return
    top.why_not = f"not named: {top.evidence.reason}"
    for c in passing[1:]:  # (unless checked below: nothing is added, so --peel would not test them)
        if c.same_symptom_as == top.effect:
            c.why_not = f"the same symptom as {top.effect}, which is not named either (its own evidence not checked)"
    # a candidate the data cannot tell from the first by its fit is checked on its own evidence (its
    # pair with the first was tried in the search). One the first fits better by more than chance is
    # not: it holds one value more easily by explaining less (a hidden servo lag, the catalogue
    # without it: tyre_relaxation failed at its bound, and body_roll, holding one value at 73% of ay
    # against a floor of 99.5%, would have been named for it)
    for nxt in [c for c in passing[1:] if indistinct(top, c)]:
        if progress:
            progress.step(f"checking {nxt.effect} at each speed")
        name = f"{model_name}+{nxt.effect}"
        nxt.evidence = nxt.evidence_alone = check_evidence(name, nxt.effect, vehicle, stretches, nxt.result,
                                                           mapper(pool, name))
        if not nxt.evidence.holds:
            nxt.why_not = f"not named: {nxt.evidence.reason}"
            continue
        nxt.significant, nxt.same_symptom_as, nxt.separable_from = True, "", {}
        top.why_not += f"; {nxt.effect} fits as well, holds one value and is named instead"
        _same_symptom(nxt, [c for c in passing if c is not top and c is not nxt and c.evidence is None])
        return


def _same_symptom(top, others) -> None:
    """``others`` (candidates that pass on their own, below ``top``) are the same symptom as
    ``top``, or cannot be told apart from it on this data where the catalogue says how to."""
    for c in others:
        advice = None
        if indistinct(top, c):
            cls_top, cls_c = available_effects()[top.effect], available_effects()[c.effect]
            advice = cls_top.confused_with.get(c.effect) or cls_c.confused_with.get(top.effect)
        if advice:
            top.separable_from[c.effect] = advice
            c.separable_from = {top.effect: advice}
            c.same_symptom_as = ""
            c.why_not = f"cannot be told apart from {top.effect} on this data: {advice}"
        else:
            c.same_symptom_as = top.effect
            c.separable_from = {}
            c.why_not = f"the same symptom as {top.effect} (--peel tests it again once that is added)"


def _name_partner(top, partner, held, n_eff) -> None:
    """``partner`` becomes the second of the named pair: its numbers are those of the joint fit,
    judged against ``top`` alone (as the pair search judged it)."""
    k = len(available_effects()[partner.effect].params)
    top.pair_with, partner.pair_with = partner.effect, top.effect
    partner.result, partner.lr, partner.p_value, partner.level = held.result, held.lr, held.p_value, top.level
    partner.gain = dict(held.gain)
    partner.delta_bic = float(k * math.log(n_eff) - held.lr) if n_eff else 0.0
    partner.evidence = held.partner_evidence
    partner.significant, partner.passes = True, True
    partner.same_symptom_as, partner.separable_from = "", {}
    partner.why_not = ""
    top.separable_from.pop(partner.effect, None)


def diagnose(runs, vehicle, model_name: str = "bicycle", peel: bool = False, max_steps: int = 4,
             progress=None, candidates=None) -> list[Diagnosis]:
    """One round, or (peel) rounds adding the winner (or the pair) until nothing is named. The
    last round carries ``unexplained``: what remains, and where.
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
            rounds.append(d)
            best = d.best
            if best is None or best.separable_from:
                break
            name, base = d.named_model, d.named_result
        last = rounds[-1]
        if progress:
            progress.step("looking where the error remains")
        final_name, final = last.named_model, last.named_result
        reasons = [f"{c.effect} is {c.why_not}" for c in last.candidates
                   if c.evidence is not None and not c.evidence.holds]
        own = max((c.screen.get("own_gain", 0.0) for c in last.candidates if c.screen), default=0.0)
        if own >= MIN_GAIN and "+" in last.model:
            # (a trial user's bicycle+tyre_relaxation on a car with a servo lag: a locked_diff was named)
            reasons.append(f"{last.model} is not where its own linearised step sees its optimum (that step gains "
                           f"{own:.1f} fit points): far from linear there, its effects may stand in for another, "
                           f"and candidates are judged poorly from it; diagnose from {parse_model_name(last.model)[0]}")
        reasons += [f"pairs tried with {c.effect}: {c.pairs.words()}" for c in last.candidates
                    if c.pairs is not None and not c.significant]
        # the final model's per-speed fits were made when its last effect's evidence was checked
        # (the same model, data and start): read there, not fitted again
        checked = last if last.best is not None else (rounds[-2] if len(rounds) > 1 else None)
        parts = checked.named_parts if checked is not None else None
        last.unexplained = describe_unexplained(final_name, final, vehicle, stretches, floor[0], floor[1], reasons,
                                                catalogue_done=last.best is None, mapper=mapper(pool, final_name),
                                                parts=parts)
        last.unexplained.pairs_tried = {c.effect: c.pairs.to_json() for c in last.candidates
                                        if c.pairs is not None and not c.significant}
    return rounds
