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
from stid.fit import convergence
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


def stop_when_stationary(prob, lo, hi, colour: float = 1.0):
    """A callback for scipy's trf that ends the solve once the Gauss-Newton step still to go,
    within the bounds and from the Jacobian at the new iterate, is below
    convergence.STEP_SE_STOP standard errors: the measure the verdict (convergence.judge)
    takes at the end, so a solve this rule stopped is never judged short of its optimum. It
    needs residuals scaled to unit noise; ``colour`` is their integrated autocorrelation time
    in samples (coloured residuals carry 1/colour of the information of white ones). scipy's
    relative ftol (1e-8) asks for far less on a long run (1e-4 of cost on 10^4 samples), and
    on a model that misses an effect trf approaches the optimum only linearly (the residuals
    are large), so a solve spent its last half there."""

    def callback(intermediate_result):
        if prob.last_jac is None or not np.array_equal(prob.last_jac[0], intermediate_result.x):
            return
        _, f, J = prob.last_jac
        if convergence.remaining_step(J, f, prob.last_jac[0], lo, hi, colour) < convergence.STEP_SE_STOP:
            raise StopIteration

    return callback


_REL_STEP = float(np.sqrt(np.finfo(float).eps))  # scipy's '2-point' relative step


class _Residuals:
    """The residual vector of x for scipy's solver, with its forward-difference Jacobian
    taken as scipy's '2-point' takes it (the same steps, one-sided, turned back at a
    bound). Owning the Jacobian lets a solve start from a point whose residuals and
    Jacobian are known already (``known``: a re-weighted solve continues where the
    previous one ended, and scipy would compute both again: n + 1 simulations)."""

    def __init__(self, residual, space: ParamSpace, lo, hi, diff_step=None, known=None, many=None):
        self.residual, self.space, self.lo, self.hi = residual, space, lo, hi
        # the residual vectors of many parameter sets at once, where the caller can (the columns of a
        # Jacobian: a linear model discretises them in one batch, Model.simulate_many)
        self.many = many or (lambda ps: [residual(p) for p in ps])
        self.diff_step = diff_step
        self.known = known
        self.last = None  # (x, f) of the newest evaluation: the differences start from it
        self.last_jac = None  # (x, f, J) of the newest Jacobian

    def fun(self, x):
        if self.known is not None and np.array_equal(x, self.known[0]):
            f = self.known[1]
        else:
            f = np.asarray(self.residual(self.space.to_p(x)), float)
        self.last = (np.array(x, float), f)
        return f

    def jac(self, x):
        if self.known is not None and self.known[2] is not None and np.array_equal(x, self.known[0]):
            self.last_jac = (np.array(x, float), self.known[1], self.known[2])
            return self.known[2]
        if self.last is None or not np.array_equal(self.last[0], x):
            self.fun(x)
        f0 = self.last[1]
        h = self._steps(x)
        # column-major: each column is written at once, and the solver's column norms and SVD
        # (LAPACK's order) read it without a copy (the column norms of 400,000 rows: 8.3 -> 0.9 ms)
        J = np.empty((f0.size, x.size), order="F")
        moved = []
        for i in range(x.size):
            x1 = x.copy()
            x1[i] = x[i] + h[i]
            moved.append(x1)
        for i, (x1, f1) in enumerate(zip(moved, self.many([self.space.to_p(x1) for x1 in moved]))):
            J[:, i] = (np.asarray(f1, float) - f0) / (x1[i] - x[i])
        self.last = (np.array(x, float), f0)
        self.last_jac = (self.last[0], f0, J)
        return J

    def _steps(self, x):
        """scipy.optimize._numdiff's absolute steps for '2-point' within the bounds."""
        sign = np.where(x >= 0, 1.0, -1.0)
        if self.diff_step is None:
            h = _REL_STEP * sign * np.maximum(1.0, np.abs(x))
        else:
            h = self.diff_step * sign * np.abs(x)
            h = np.where((x + h) - x == 0, _REL_STEP * sign * np.maximum(1.0, np.abs(x)), h)
        lower, upper = x - self.lo, self.hi - x
        out = (x + h < self.lo) | (x + h > self.hi)
        fits = np.abs(h) <= np.maximum(lower, upper)
        h = np.where(out & fits, -h, h)
        return np.where(fits, h, np.where(upper >= lower, upper, -lower))


def least_squares(residual, space: ParamSpace, starts: list, unit_noise: bool = False, known=None,
                  colour: float = 1.0, many=None, **kw):
    """Run scipy's bounded trust-region least squares from each start; keep the best.
    ``unit_noise``: the residuals are scaled to unit noise, so the solve stops once it is
    statistically at the optimum (stop_when_stationary), in standard errors of residuals
    whose integrated autocorrelation time is ``colour`` samples. ``known``: (x, residuals,
    Jacobian) at the first start, in the solver's coordinates, when the caller has them
    (the Jacobian may be None: then only the residuals are known). ``many(ps)``: the residuals of
    many parameter sets at once, where the caller has a faster way than one by one."""
    lo, hi = space.bounds_x()
    diff_step = None
    if getattr(space.model, "nonlinear", False):
        # an iterated simulation is exact only to its tolerance: difference over a step
        # large enough that the tolerance does not show in the Jacobian
        diff_step = kw.pop("diff_step", 1e-5)
    best = None
    for k, p0 in enumerate(starts):
        x0 = np.clip(space.to_x(p0), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        start_known = None
        if k == 0 and known is not None and np.allclose(known[0], x0, rtol=1e-12, atol=1e-12):
            # the same point (up to the round trip through physical units): start exactly there
            x0 = start_known = np.array(known[0], float)
        prob = _Residuals(residual, space, lo, hi, diff_step,
                          (x0, known[1], known[2]) if start_known is not None else None, many)
        if unit_noise:
            kw["callback"] = stop_when_stationary(prob, lo, hi, colour)
        try:
            res = optimize.least_squares(prob.fun, x0, jac=prob.jac, bounds=(lo, hi), method="trf",
                                         x_scale="jac", **kw)
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
