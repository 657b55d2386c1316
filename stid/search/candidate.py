"""A candidate effect of one diagnosis round, and the chance arithmetic that judges it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri  # (scipy.stats costs 0.4 s to import)

from stid.models.effect import available_effects

ALPHA = 0.01
MIN_GAIN = 0.5  # fit points
GAP_FRACTION = 0.25
OUTS = ("ay", "r")


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
    screen: dict = field(default_factory=dict)  # the linearised step's prediction (see stid.search.screen)
    start: dict | None = None  # where the screen's step landed: a start for the full fit
    pairs: object = None  # stid.search.pairs.PairSearch, when its evidence failed alone
    pair_with: str = ""  # the effect named together with it (fitted jointly: stid.search.pairs)

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
        if self.pair_with:
            out["named_with"] = self.pair_with
        if self.pairs is not None:
            out["pairs"] = self.pairs.to_json()
        return out


def lr_statistic(base, res, n_eff) -> float:
    """LR statistic of ``res`` against ``base`` with the effective sample size, outputs treated
    as independent."""
    eb = np.vstack([p.y[p.keep] - p.yhat[p.keep] for p in base.predictions])
    er = np.vstack([p.y[p.keep] - p.yhat[p.keep] for p in res.predictions])
    ratio = np.mean(eb ** 2, axis=0) / np.maximum(np.mean(er ** 2, axis=0), 1e-300)
    return float(n_eff * np.sum(np.log(ratio)))


def indistinct(top, c) -> bool:
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
