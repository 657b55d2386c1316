"""Pairs before "the catalogue lacks it".

When the best candidate's evidence fails (its parameter is not one value across speed, or
stops at a bound), a second missing effect may be bending it: with a locked differential
in the car, a servo lag fits 29 ms at 3 m/s and 16 ms at 7 m/s. The candidate is then
fitted jointly with every other effect of the catalogue the data can test. Which partners
get a joint fit, and in which order, is decided by the screen's linearised step taken from
the candidate's own fit: from the base model, where the candidate's symptom fills the
residual, the partner can look like chance (a locked differential beside a servo lag did).

A joint fit names the pair when the partner adds more than chance and enough fit to the
candidate (the rules a candidate meets on its own, stid.diagnose) and both parameters hold
as one value across the evidence (stid.analysis.evidence). When the candidate's value holds
with the partner but the partner's does not, the candidate is named alone and ``--peel``
tests the partner again. Every partner is recorded with its verdict, so that "the catalogue
lacks it" is said only after the pairs, naming them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc  # chi-square survival function

from stid.analysis.evidence import check_evidence
from stid.analysis.kinematics import kinematic_veto
from stid.models.effect import available_effects
from stid.search.candidate import GAP_FRACTION, MIN_GAIN, OUTS, Candidate, lr_statistic, p_in_words
from stid.search.candidate_fit import fit_candidate
from stid.search.pool import WORKERS, Ahead, in_workers, mapper
from stid.search.screen import linearised_steps, sift

# verdicts of one partner, in the order of how far it got
SCREENED = "screened out"  # the step from the first's fit: within chance, or too small to matter
NOT_TESTED = "not tested"  # the data cannot test the partner at all (it was skipped in the round)
NOTHING = "adds nothing"  # the joint fit: no more than chance, or too little, beyond the first
RULED_OUT = "ruled out"  # the joint fit's sensor offsets (either effect's) are not what the data's kinematics show
BENT = "first still bent"  # the first's parameter is still not one value with it
FIRST_HOLDS = "first holds"  # the first's value holds with it, the partner's own does not: no evidence
NAMED = "named"  # both hold: the pair is named
NOT_NEEDED = "not needed"  # not fitted: a partner before it made the first hold


@dataclass
class PairTry:
    """One partner of the first candidate, and how far its pair got."""

    partner: str
    verdict: str
    why: str = ""
    result: object = None  # the joint fit
    lr: float = 0.0  # the joint fit against the first alone
    p_value: float = 1.0
    gain: dict = field(default_factory=dict)  # fit points over the first alone
    evidence: object = None  # the first's, in the joint fit
    partner_evidence: object = None

    def to_json(self, first: str) -> dict:
        """``first``: the effect it was paired with (its parameters in the joint fit are given too)."""
        out = {"effect": self.partner, "verdict": self.verdict, "why": self.why}
        if self.verdict in (SCREENED, NOT_TESTED, NOT_NEEDED):
            if self.gain:
                out["predicted_gain"] = {o: round(v, 2) for o, v in self.gain.items()}
            return out
        res = self.result
        own = [n for n in res.names if res.owners.get(n) in (first, self.partner)]
        ci = dict(zip(res.names, res.ci95))
        out.update({"fit": {o: round(v, 2) for o, v in res.fit.items()}, "lr": round(self.lr, 1),
                    "p_value": float(f"{self.p_value:.3g}"),
                    "params": {n: res.value(n) for n in own},
                    "intervals": {n: None if ci[n] is None else [float(ci[n][0]), float(ci[n][1])] for n in own}})
        for key, ev in (("evidence", self.evidence), ("partner_evidence", self.partner_evidence)):
            if ev is not None:
                out[key] = {"holds": ev.holds, "reason": ev.reason}
        return out


@dataclass
class PairSearch:
    """The first candidate's pairs: every other catalogue effect, each with its verdict."""

    first: str
    model: str  # the model the partners were screened from: the base with the first added
    tried: list = field(default_factory=list)  # [PairTry], in the order they were judged

    def _with(self, *verdicts):
        return next((t for t in self.tried if t.verdict in verdicts), None)

    @property
    def named(self):
        """The pair named (its PairTry), or None."""
        return self._with(NAMED)

    @property
    def holds_with(self):
        """The partner with which the first's value holds and its own does too (its PairTry), or
        None. A partner whose own parameter is not one value is a fudge, not a second effect: the
        first holding beside it is no evidence for the first (an accelerometer scale error the
        catalogue lacks made gyro_scale hold beside a locked diff whose moment moved 3x with speed)."""
        return self._with(NAMED)

    def words(self) -> str:
        """Which pairs were tried and how each ended, for `unexplained` and the text."""
        fitted = [t for t in self.tried if t.result is not None]
        parts = []
        if fitted:
            parts.append(f"fitted jointly with {self.first}: "
                         + "; ".join(f"{t.partner} ({t.why})" for t in fitted))
        for verdict, what in ((SCREENED, f"ruled out by a linearised step from {self.model}"),
                              (NOT_TESTED, "not testable on this data")):
            group = [t for t in self.tried if t.verdict == verdict]
            if group:
                parts.append(f"{what}: " + ", ".join(f"{t.partner} ({t.why})" for t in group))
        return "; ".join(parts) if parts else f"no other catalogue effect to pair {self.first} with"

    def to_json(self) -> dict:
        return {"first": self.first, "screened_from": self.model, "tried": [t.to_json(self.first) for t in self.tried]}


def search_pairs(model_name, top, others, vehicle, stretches, n_eff, floor, pool=None, ahead=None,
                 progress=None) -> PairSearch:
    """``top``'s pairs with each of ``others`` (the round's other candidates), up to the first
    with which ``top``'s value holds. ``ahead``: a Future of ``pair_start`` (started in a worker
    beside ``top``'s evidence check, see ``start_ahead``), or None."""
    search = PairSearch(top.effect, f"{model_name}+{top.effect}")
    search.tried = [PairTry(o.effect, NOT_TESTED, o.skipped) for o in others if o.skipped]
    testable = [o for o in others if not o.skipped]
    if not testable:
        return search
    first = None
    if ahead is not None and not ahead.cancel():
        steps, kept, first = ahead.result()
    else:
        steps, kept = sift_partners(model_name, top, testable, vehicle, stretches, n_eff)
    said = f"screened out: a linearised step from {search.model} "  # (said once, in PairSearch.words)
    search.tried += [PairTry(s.effect, SCREENED, s.why_not.removeprefix(said).removeprefix("is "), gain=s.gain)
                     for s in steps if s.effect not in kept]
    by_effect = {s.effect: s for s in steps}
    partners = [by_effect[e] for e in kept]
    names = [f"{search.model}+{p.effect}" for p in partners]
    # the joint fits are independent: they start in the workers one per core ahead of need, and
    # are read here in order, up to the first with which the first's value holds (the likeliest
    # partner is first, so usually one fit). When the first was fitted ahead, the next starts
    # only when needed: started now, it would slow the first's check, which usually ends the search
    joint = Ahead(pool if all(in_workers(n) for n in names) else None, fit_candidate,
                  joint_jobs(model_name, top, partners, _alone(others), vehicle, stretches),
                  window=WORKERS if first is None else 1, known={0: first} if first is not None else None)
    gap = {o: max(floor[o] - top.result.fit[o], 0.0) if floor and np.isfinite(floor[o]) else 0.0 for o in OUTS}
    for i, (p, name2) in enumerate(zip(partners, names)):
        if search.holds_with is not None:
            search.tried.append(PairTry(p.effect, NOT_NEEDED, f"{top.effect} held with "
                                        f"{search.holds_with.partner} first", gain=p.gain))
            continue
        if progress:
            progress.step(f"checking {top.effect} with {p.effect}")
        t = _judge(top, p.effect, joint.result(i), n_eff, gap, stretches)
        search.tried.append(t)
        if t.verdict:
            continue
        t.evidence = check_evidence(name2, top.effect, vehicle, stretches, t.result, mapper(pool, name2))
        if not t.evidence.holds:
            t.verdict, t.why = BENT, f"{top.effect} is still not one value: {t.evidence.reason}"
            continue
        t.partner_evidence = check_evidence(name2, p.effect, vehicle, stretches, t.result, mapper(pool, name2),
                                            parts=t.evidence.partitions)
        if t.partner_evidence.holds:
            t.verdict, t.why = NAMED, f"both hold as one value across {_across(t.evidence)}"
        else:
            t.verdict, t.why = FIRST_HOLDS, (f"{top.effect} holds with it, {p.effect} itself does not: "
                                             f"{t.partner_evidence.reason}")
    joint.drop_the_rest()
    return search


def _judge(top, partner: str, both, n_eff, gap, stretches) -> PairTry:
    """The partner's chance and size tests in the joint fit, against ``top`` alone, and the
    kinematics' check of both effects as fitted jointly (the rules a candidate meets in a round
    of its own); an empty verdict when it passes them."""
    k2 = len(available_effects()[partner].params)
    lr = max(lr_statistic(top.result, both, n_eff), 0.0) if n_eff is not None else 0.0
    t = PairTry(partner, "", result=both, lr=lr, p_value=float(chdtrc(k2, lr)),
                gain={o: both.fit[o] - top.result.fit[o] for o in OUTS})
    need = {o: max(MIN_GAIN, GAP_FRACTION * gap[o]) for o in OUTS}
    if not both.converged:  # where a solver stopped is no second opinion either way
        t.verdict, t.why = NOTHING, "its joint fit did not converge: " + both.status.split("not an optimum: ")[-1]
    elif t.p_value >= top.level:
        # it sits at or near its off value: a joint fit that is the first alone is no second opinion
        t.verdict, t.why = NOTHING, f"beside {top.effect}: {p_in_words(t.p_value, top.level)}"
    elif not any(t.gain[o] >= need[o] for o in OUTS):
        t.verdict, t.why = NOTHING, ("adds too little to " + top.effect + ": "
                                     + ", ".join(f"{o} {t.gain[o]:+.2f}" for o in OUTS) + " fit points")
    else:  # a sensor offset the data's own kinematics rule out is no finding, in a pair as alone
        veto = next(((e, v) for e in (partner, top.effect) if (v := kinematic_veto(e, both, stretches))), None)
        if veto is not None:
            t.verdict, t.why = RULED_OUT, f"{veto[0]} as fitted with it: {veto[1]}"
    return t


def _across(ev) -> str:
    return " and ".join(ev.partitions) if ev.partitions else "the data"


def sift_partners(model_name, top, others, vehicle, stretches, n_eff):
    """Every partner's linearised step from ``top``'s fit, likeliest first, and the effects the
    screen keeps (``screen.sift`` at ``top``'s level; an effect with no off value is kept).
    Returns ([Candidate with the step's numbers], [kept effects, likeliest first])."""
    trial = [Candidate(o.effect) for o in others]
    unstepped, stepped = linearised_steps(f"{model_name}+{top.effect}", trial, vehicle, stretches, top.result,
                                          n_eff or 1.0, top.level)
    stepped.sort(key=lambda c: -c.lr)
    kept = [c.effect for c in unstepped] + [c.effect for c in stepped
                                            if sift(c, f"{model_name}+{top.effect}", top.level)]
    return unstepped + stepped, kept


def _alone(others) -> dict:
    """Effect -> the parameters of its fit alone (none for one the screen passed over)."""
    return {o.effect: o.result.all_params() if o.result is not None else {} for o in others}


def joint_jobs(model_name, top, partners, alone: dict, vehicle, stretches) -> list:
    """The joint fits of ``top`` with each partner (``fit_candidate`` jobs): from ``top``'s fit
    with the partner at its off value, its default, where the step from ``top``'s fit landed,
    or where the partner was fitted alone, whichever fits best."""
    return [(f"{model_name}+{top.effect}", p.effect, vehicle, stretches, top.result.all_params(), p.start,
             [alone.get(p.effect) or {}]) for p in partners]


def start_ahead(pool, model_name, top, others, vehicle, stretches, n_eff, floor):
    """The search's first step (the partners' steps, the joint fit with the likeliest),
    started in a worker beside ``top``'s evidence check when a search is likely: the named
    effect leaves the data short of the noise floor by what a second effect could still be
    named for (MIN_GAIN). Where one effect is missing, the named one reaches the floor and
    nothing is started. A guess about timing only: whether the search runs is the check's
    answer. A Future of ``pair_start``'s answer, or None."""
    testable = [o for o in others if not o.skipped]
    if pool is None or not testable or floor is None or n_eff is None:
        return None
    short = [o for o in OUTS if np.isfinite(floor[o]) and floor[o] - top.result.fit[o] >= MIN_GAIN]
    if not short or not all(in_workers(f"{model_name}+{top.effect}+{o.effect}") for o in testable):
        return None
    # the others travel light: their effects and parameters (the joint fits' starts), not their fits
    light = [Candidate(o.effect) for o in testable]
    return pool.submit(pair_start, (model_name, top, light, _alone(testable), vehicle, stretches, n_eff))


def pair_start(args):
    """(the partners' steps, the kept effects, the joint fit with the first kept or None)."""
    model_name, top, others, alone, vehicle, stretches, n_eff = args
    steps, kept = sift_partners(model_name, top, others, vehicle, stretches, n_eff)
    if not kept:
        return steps, kept, None
    first = next(s for s in steps if s.effect == kept[0])
    (job,) = joint_jobs(model_name, top, [first], alone, vehicle, stretches)
    return steps, kept, fit_candidate(job)

