"""Whether a fit is an optimum, and which of its parameters the data determine.

scipy's trust-region solver stops for reasons that are not all "found the
minimum": ``xtol`` (status 3) also ends a solve whose steps keep failing because
the cost is not smooth where it stands (an iterated tyre model that did not
settle: its residuals are noise in the parameters), and a solve can end on its
evaluation budget. So the solver's status is reported as it is, and the
verdict is taken from the answer itself:

- the model's own simulation settled there (an iterated nonlinear tyre force
  converged; a linear model always does);
- the Gauss-Newton step that is left, within the bounds, is a small part of a
  standard error. At any stationary point that step is zero whatever the size of
  the residuals (it is the gradient, measured in the Jacobian's own metric), so
  this asks "is it stationary, to within what the data can resolve", which no
  tolerance on the cost or the step length says.

A parameter is not determined when the fit did not converge, when it sits on a
bound (its interval would be cut by the bound, and the data asked for more), or
when the Jacobian is rank-deficient in its direction (its covariance is then the
pseudo-inverse's zero: an interval of zero width that claims a precision the data
do not have). Such a parameter gets no interval at all.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# The step still to go, in standard errors of the direction it points in: a solve stops below
# STEP_SE_STOP (stid.fit.solver ends scipy's solve there, closer than that moves no reported
# figure), and a fit that ends beyond STEP_SE_MAX has not reached the optimum (half of one moves a
# 95% interval's centre by a quarter of its half-width). One measure for both, so a solve that
# stopped by its rule is always called converged, and the margin between them is what the
# quadratic model may be off by where the model misses an effect (its residuals are large).
STEP_SE_STOP = 0.1
STEP_SE_MAX = 0.5
# Singular values of the column-scaled Jacobian below this share of the largest: directions the
# data do not see. scipy's difference Jacobian is good to ~1e-8 of a column; the covariance's
# pseudo-inverse (stid.fit.solver._pinv_sym) drops directions below 1e-12 of J^T J, this squared.
RANK_RCOND = 1e-6
NULL_SHARE = 0.3  # a parameter takes part in a null direction with at least this weight in it

NOT_CONVERGED = "the fit did not converge"
AT_BOUND = "at its bound"


@dataclass
class Verdict:
    """What a fit can claim: ``converged`` (an optimum the data resolve), ``status`` (the
    solver's words and the reason for the verdict), ``at_bound`` (parameters on a bound) and
    ``undetermined`` (parameter -> why it has no interval)."""

    converged: bool = True
    status: str = ""
    at_bound: list = field(default_factory=list)
    undetermined: dict = field(default_factory=dict)
    step_se: float = 0.0  # the Gauss-Newton step still to go, in standard errors


def solver_words(res) -> str:
    """scipy's own message, its status number and how many evaluations it took (status -2 is
    stid's own stopping rule, stid.fit.solver.stop_when_stationary, ending the solve through scipy's
    callback)."""
    words = res.message.rstrip(".")
    if res.status == -2:
        words = (f"stopped by stid's rule: the Gauss-Newton step still to go is below {STEP_SE_STOP:g} of a "
                 "standard error")
    return f"{words} (scipy least_squares status {res.status}, {res.nfev} evaluations)"


def remaining_step(J: np.ndarray, r: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   colour: float = 1.0) -> float:
    """The Gauss-Newton step from ``x`` that stays within [lo, hi], as the cost it would still
    lose over what one standard error of that direction is worth: sqrt of that ratio (the step's
    length in standard errors). J, r: Jacobian and residuals scaled to unit noise up to a common
    factor (the reduced chi-square takes it out); ``colour``: the residuals' integrated
    autocorrelation time in samples (each carries 1/colour of a white sample's information).

    Solved on the p x p normal equations, not the n rows: |r + J s|^2 = |r|^2 - |c|^2 + |R s + c|^2
    for any R, c with R^T R = J^T J and R^T c = J^T r, so the bounded step is the same and costs
    no more than one product J^T J (the solver asks this after every iteration)."""
    from scipy.optimize import lsq_linear

    n, p = J.shape
    H, g, rr = J.T @ J, J.T @ r, float(r @ r)  # a non-finite entry of J or r shows in these
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(g)) and np.isfinite(rr)):
        return float("inf")
    norms = np.sqrt(np.diag(H))
    seen = norms > 0
    if not np.any(seen):
        return 0.0
    ns = norms[seen]
    lam, V = np.linalg.eigh(H[np.ix_(seen, seen)] / np.outer(ns, ns))  # of the column-scaled Jacobian
    kept = lam > RANK_RCOND ** 2 * lam[-1]  # directions the data see (null_directions names the others)
    R = np.sqrt(lam[kept])[:, None] * V[:, kept].T
    c = (V[:, kept].T @ (g[seen] / ns)) / np.sqrt(lam[kept])
    # bounds in the scaled coordinates; a bound already reached stays closed (a hair inside)
    lo_s = (lo - x)[seen] * ns
    hi_s = (hi - x)[seen] * ns
    lo_s, hi_s = np.minimum(lo_s, 0.0), np.maximum(hi_s, 0.0)
    step = lsq_linear(R, -c, bounds=(lo_s, hi_s + 1e-300), method="bvls").x
    lose = float(c @ c - np.sum((c + R @ step) ** 2))
    chi2 = rr / max(n - p, 1)
    return float(np.sqrt(max(lose, 0.0) / (max(chi2, 1e-300) * max(colour, 1.0))))


def null_directions(J: np.ndarray, names: list) -> dict:
    """Parameters in a direction the Jacobian does not see (rank deficiency): name -> why."""
    norms = np.linalg.norm(J, axis=0)
    out = {}
    for n, c in zip(names, norms):
        if not c > 0:
            out[n] = "the data do not change with it"
    live = [i for i, c in enumerate(norms) if c > 0]
    if len(live) < 2:
        return out
    _, s, vt = np.linalg.svd(J[:, live] / norms[live], full_matrices=False)
    for k in np.flatnonzero(s < RANK_RCOND * s[0]):
        members = [names[live[i]] for i in np.flatnonzero(np.abs(vt[k]) >= NULL_SHARE)]
        for n in members:
            others = [m for m in members if m != n]
            out.setdefault(n, "the data do not tell it from " + ", ".join(others) if others
                           else "the data do not change with it")
    return out


def judge(res, space, colour: float = 1.0, simulation_settled: bool = True) -> Verdict:
    """The verdict on a solve ``res`` (scipy's result, Jacobian at its end) in ``space``
    (stid.fit.solver.ParamSpace). ``simulation_settled``: the model's simulation converged at
    the answer (False for an iterated tyre force that did not)."""
    words = solver_words(res)
    at_bound = space.at_bound(res.x)
    lo, hi = space.bounds_x()
    step = remaining_step(res.jac, res.fun, res.x, lo, hi, colour)
    reasons = []
    if res.status in (0, -1):
        reasons.append("the solver gave up before it met a stopping rule")
    if not simulation_settled:
        reasons.append("the model's simulation did not settle at the answer (its tyre forces are iterated, "
                       "and the iteration did not converge: there the model car slides out)")
    if not np.isfinite(step) or step > STEP_SE_MAX:
        unsettled = getattr(res, "weights_settled", True) is False
        reasons.append((f"the cost still falls from where it stopped (a step of {step:.3g} standard errors "
                        "is left" + (": the outputs' weights had not settled, and at the residual levels the "
                                     "last solve left, not the weights it was solved with, it is not stationary"
                                     if unsettled else "") + ")")
                       if np.isfinite(step) else "its residuals or Jacobian are not finite")
    converged = not reasons
    undetermined = {}
    if not converged:
        undetermined = {n: NOT_CONVERGED for n in space.free}
    else:
        for n in at_bound:
            undetermined[n] = AT_BOUND
        for n, why in null_directions(res.jac, list(space.free)).items():
            undetermined.setdefault(n, why)
    status = words if converged else f"{words}; not an optimum: {'; '.join(reasons)}"
    return Verdict(converged, status, at_bound, undetermined, step if np.isfinite(step) else float("inf"))
