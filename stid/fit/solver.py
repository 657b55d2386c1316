"""Bounded, scaled least squares shared by the frequency- and time-domain fits.

Positive physical parameters (stiffness, inertia, time constants, lengths) are
fitted in log space, the others scaled by their bound span, so one step size
suits N/rad and metres alike. Covariances come from the Jacobian at the optimum,
mapped back to physical units (delta method); a sandwich estimator handles
coloured residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from stid.errors import InputError
from stid.stats import autocorr_length


@dataclass
class ParamSpace:
    model: object
    free: list
    fixed: dict  # name -> value
    lower: dict = field(default_factory=dict)
    upper: dict = field(default_factory=dict)
    derived: object = None  # callable(p) -> dict of values computed from the others

    def __post_init__(self):
        for name in self.free:
            lo, hi = self.model.bounds(name)
            self.lower.setdefault(name, lo)
            self.upper.setdefault(name, hi)
        self._log = [self.model.param(n).log for n in self.free]
        self._span = [max(self.upper[n] - self.lower[n], 1e-12) for n in self.free]

    def to_x(self, p: dict) -> np.ndarray:
        x = []
        for n, lg, sp in zip(self.free, self._log, self._span):
            v = min(max(p[n], self.lower[n]), self.upper[n])
            x.append(np.log(max(v, 1e-300)) if lg else v / sp)
        return np.asarray(x)

    def to_p(self, x: np.ndarray) -> dict:
        p = dict(self.fixed)
        for n, lg, sp, xi in zip(self.free, self._log, self._span, x):
            p[n] = float(np.exp(xi)) if lg else float(xi * sp)
        if self.derived is not None:
            p.update(self.derived(p))
        return p

    def bounds_x(self):
        lo = [np.log(max(self.lower[n], 1e-300)) if lg else self.lower[n] / sp
              for n, lg, sp in zip(self.free, self._log, self._span)]
        hi = [np.log(self.upper[n]) if lg else self.upper[n] / sp
              for n, lg, sp in zip(self.free, self._log, self._span)]
        return np.asarray(lo), np.asarray(hi)

    def dp_dx(self, x: np.ndarray) -> np.ndarray:
        return np.asarray([np.exp(xi) if lg else sp for xi, lg, sp in zip(x, self._log, self._span)])

    def at_bound(self, x: np.ndarray, tol: float = 1e-3) -> list:
        lo, hi = self.bounds_x()
        span = hi - lo
        return [n for n, xi, a, b, s in zip(self.free, x, lo, hi, span) if xi - a < tol * s or b - xi < tol * s]


def starting_points(model, space: ParamSpace, p0: dict, multistart: bool) -> list:
    """p0, and (multistart) p0 with every free effect parameter at 0.3x and 3x: lags and
    lengths make the cost non-convex, and a second basin is a factor away, not a step."""
    starts = [p0]
    if not multistart:
        return starts
    for f in (0.3, 3.0):
        q = dict(p0)
        for e in model.effects:
            for par in e.params:
                if par.log and par.multistart and par.name in space.free:
                    q[par.name] = p0[par.name] * f
        if q != p0:
            starts.append(q)
    return starts


# Residuals scaled to unit noise: a solve stops once the cost it can still lose is below
# this, half the square of a tenth of a standard error (of white noise; the intervals a fit
# reports are wider, its residuals being coloured). Closer than that to the optimum moves no
# reported figure; scipy's relative ftol (1e-8) asks for 1e-4 of cost on 10^4 samples, and on
# a model that misses an effect Gauss-Newton approaches it only linearly (the residuals are
# large), so the last half of a solve was spent there.
SETTLED_COST = 0.5 * 0.1 ** 2


def settled(tol: float = SETTLED_COST):
    """A callback for scipy's trf that stops the solve when the cost still to lose is below
    ``tol``, estimated from the last three reductions as a geometric series (the slower of
    the last two ratios, so one lucky step does not end it)."""
    costs = []

    def callback(intermediate_result):
        costs.append(float(intermediate_result.cost))
        if len(costs) < 4:
            return
        d = -np.diff(costs[-4:])
        if np.any(d <= 0):
            return
        rho = max(d[1] / d[0], d[2] / d[1])
        if rho < 1.0 and d[2] * rho / (1.0 - rho) < tol:
            raise StopIteration

    return callback


def least_squares(residual, space: ParamSpace, starts: list, unit_noise: bool = False, **kw):
    """Run scipy's bounded trust-region least squares from each start; keep the best.
    ``unit_noise``: the residuals are scaled to unit noise, so the solve may stop once
    it is statistically at the optimum (SETTLED_COST)."""
    lo, hi = space.bounds_x()
    if getattr(space.model, "nonlinear", False):
        # an iterated simulation is exact only to its tolerance: difference over a step
        # large enough that the tolerance does not show in the Jacobian
        kw.setdefault("diff_step", 1e-5)
    best = None
    for p0 in starts:
        x0 = np.clip(space.to_x(p0), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        if unit_noise:
            kw["callback"] = settled()
        try:
            res = optimize.least_squares(lambda x: residual(space.to_p(x)), x0, bounds=(lo, hi),
                                         method="trf", x_scale="jac", **kw)
        except (np.linalg.LinAlgError, ValueError) as e:
            raise InputError(f"the fit failed numerically ({e}); check the data for outliers") from None
        if best is None or res.cost < best.cost:
            best = res
    return best


def _pinv_sym(H: np.ndarray) -> np.ndarray:
    return np.linalg.pinv(H, rcond=1e-12, hermitian=True)


def covariance_white(J: np.ndarray, r: np.ndarray, n_params: int, scale_by_chi2: bool = True) -> np.ndarray:
    """(J^T J)^-1 for residuals already divided by their standard deviation, inflated by the
    reduced chi-square when the model does not reach the noise level."""
    cov = _pinv_sym(J.T @ J)
    dof = max(len(r) - n_params, 1)
    chi2 = float(r @ r) / dof
    return cov * max(chi2, 1.0) if scale_by_chi2 else cov


def covariance_sandwich(J_blocks: list, r_blocks: list) -> np.ndarray:
    """Newey-West (Bartlett) sandwich covariance for time-series residuals.

    Each block is one stretch: J (n_t, n_out, p) and r (n_t, n_out), residuals already
    scaled by their standard deviation. Output-error residuals are coloured (the model
    error is filtered by the vehicle), so the white-noise formula understates the
    uncertainty; the sandwich does not.
    """
    p = J_blocks[0].shape[2]
    H = np.zeros((p, p))
    Omega = np.zeros((p, p))
    for J, r in zip(J_blocks, r_blocks):
        n = len(r)
        g = np.einsum("top,to->tp", J, r)  # score per time sample
        H += np.einsum("top,toq->pq", J, J)
        L = max(autocorr_length(r[:, k], max(1, n // 10)) for k in range(r.shape[1]))
        L = int(min(max(2 * L, 5), n // 4))
        Om = g.T @ g
        for lag in range(1, L + 1):
            w = 1.0 - lag / (L + 1)
            G = g[lag:].T @ g[:-lag]
            Om += w * (G + G.T)
        Omega += Om
    Hi = _pinv_sym(H)
    return Hi @ Omega @ Hi


def to_physical(cov_x: np.ndarray, space: ParamSpace, x: np.ndarray) -> np.ndarray:
    D = np.diag(space.dp_dx(x))
    return D @ cov_x @ D
