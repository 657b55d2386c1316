"""Steady-state cornering (study 1, eq. 12 and 15):

    delta = L/R + eta ay,          eta = m/L (b/Cf - a/Cr)   [rad per m/s^2]
    beta  = b/R - m a/(L Cr) ay

with the path radius R = vx / r. Two straight lines against ay: the steer line
gives the understeer gradient eta, the body-slip line gives Cr, and both
together give Cf. Without a body-slip measurement only eta is identifiable.
A constant offset is fitted on each line (steering trim, slip sensor zero).
"""

from __future__ import annotations

import numpy as np

from stid.errors import InputError
from stid.fit.dataset import SteadyPoints
from stid.fit.result import FitResult, fit_percent


CLOSED_FORM = "closed form: ordinary least squares on the steady-state lines (no iterations)"
LINEAR_AY = 0.4 * 9.81  # m/s^2: about where tyres leave their linear range (0.4 g)
BENDS_Z = 3.0  # the steer line's curvature beyond this many standard errors: it bends


def _line(x, y):
    """OLS y = k x + c: (k, c), covariance, residuals."""
    X = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ coef
    dof = max(len(y) - 2, 1)
    cov = np.linalg.inv(X.T @ X) * (e @ e) / dof
    return coef, cov, e


def fit_steady(model, pts: SteadyPoints) -> FitResult:
    v = model.vehicle
    m, a, b, L = v.mass, v.a, v.b, v.L
    n = len(pts.ay)
    if n < 5:
        raise InputError(f"only {n} steady-state points found (need >= 5): drive circles at constant "
                         "steer while the speed changes slowly, over a range of lateral acceleration")
    if np.ptp(pts.ay) < 1.0:
        raise InputError(f"the steady-state points span only {np.ptp(pts.ay):.2f} m/s^2 of lateral "
                         "acceleration; sweep the speed further (a range of several m/s^2 is needed)")
    inv_R = pts.r / pts.vx
    (eta, d0), cov_d, e_d = _line(pts.ay, pts.steer - L * inv_R)
    steer_hat = L * inv_R + eta * pts.ay + d0
    warnings = ["Iz is not identifiable from steady-state data (no yaw acceleration); "
                "use --method two-step or freq with random steer"]
    if model.effects:
        warnings.append("the steady-state fit uses the plain bicycle relations; effects in the model "
                        f"({', '.join(e.name for e in model.effects)}) are ignored")
    given = sorted(set(getattr(v, "params", None) or {}) & set(model.param_names))
    if given:
        warnings.append(f"the steady-state lines are solved in closed form: the vehicle file's [params] "
                        f"({', '.join(given)}) set no start and no bound on what they give")
    bends = _bends_beyond_linear(pts.ay, pts.steer - L * inv_R)
    if bends:
        warnings.insert(0, bends)
    fit = {"steer": fit_percent(pts.steer, steer_hat)}
    extra = {"points": pts, "eta": eta, "delta0": d0}
    if pts.beta is None:
        warnings.insert(0, "body slip angle beta is not measured: from steady state only the understeer "
                           "gradient eta = m/L (b/Cf - a/Cr) is identifiable, not Cf and Cr separately")
        res = FitResult(model=model.name, method="steady", names=["eta"], values=np.array([eta]),
                        cov=cov_d[:1, :1], units={"eta": "rad/(m/s^2)"}, fit=fit, n=n, warnings=warnings,
                        extra=extra)
        res.loglik = _loglik(e_d)
        res.status = CLOSED_FORM
        return res
    (kb, b0), cov_b, e_b = _line(pts.ay, pts.beta - b * inv_R)
    if kb >= 0:
        raise InputError("body slip does not decrease with lateral acceleration as a single-track "
                         "car's must (slope >= 0): check the sign convention of beta (ISO 8855)")
    Cr = -m * a / (L * kb)
    denom = eta * L / m + a / Cr
    if denom <= 0:
        raise InputError("the steady-state lines give a negative front stiffness: the data are not "
                         "consistent with the single-track model (check steer calibration)")
    Cf = b / denom
    # delta method, the two lines treated as independent
    dCr_dk = m * a / (L * kb ** 2)
    dCf_deta = -b / denom ** 2 * (L / m)
    dCf_dk = -b / denom ** 2 * (-a / Cr ** 2) * dCr_dk
    Jm = np.array([[0.0, dCr_dk], [dCf_deta, dCf_dk]])  # rows Cr, Cf over (eta, k)
    S = np.diag([cov_d[0, 0], cov_b[0, 0]])
    cov = Jm @ S @ Jm.T
    order = [1, 0]  # Cf, Cr
    cov = cov[np.ix_(order, order)]
    beta_hat = b * inv_R + kb * pts.ay + b0
    fit["beta"] = fit_percent(pts.beta, beta_hat)
    extra.update({"k_beta": kb, "beta0": b0})
    res = FitResult(model=model.name, method="steady", names=["Cf", "Cr"], values=np.array([Cf, Cr]), cov=cov,
                    units={"Cf": "N/rad", "Cr": "N/rad"}, owners={"Cf": "bicycle", "Cr": "bicycle"}, fit=fit,
                    positive=("Cf", "Cr"),
                    n=2 * n, warnings=warnings, extra=extra)
    res.loglik = _loglik(e_d) + _loglik(e_b)
    res.status = CLOSED_FORM
    return res


def _bends_beyond_linear(ay: np.ndarray, y: np.ndarray) -> str:
    """Words where the points reach past the tyres' linear range and the steer line (``y``: steer less
    L/R against ``ay``) bends there; empty otherwise. A trial's circle ramped to 19 m/s^2 (2 g): eta
    came out -5.1e-5 +- 0.2e-5 rad/(m/s^2), the car's linear gradient -1.7e-5, without a word."""
    top = float(np.max(np.abs(ay)))
    if top <= LINEAR_AY or len(ay) < 8:
        return ""
    X = np.column_stack([ay, ay * np.abs(ay), np.ones_like(ay)])  # (odd: a saturation bends both sides alike)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ coef
    cov = np.linalg.pinv(X.T @ X) * (e @ e) / max(len(y) - 3, 1)
    z = coef[1] / np.sqrt(max(cov[1, 1], 1e-300))
    if not abs(z) > BENDS_Z:
        return ""
    words = (f"the steady points reach |ay| {top:.1f} m/s^2 ({top / 9.81:.1f} g), past the tyres' linear range "
             f"(about {LINEAR_AY:.1f} m/s^2), and the steer line bends there (curvature z = {z:.0f}): eta is a "
             "mean over the tyres' saturation, not their linear gradient")
    inside = np.abs(ay) <= LINEAR_AY
    if inside.sum() >= 5 and np.ptp(ay[inside]) >= 1.0:
        (k, _), cov_in, _ = _line(ay[inside], y[inside])
        words += (f"; on the {int(inside.sum())} points within it, eta = {k:.3g} (std. error "
                  f"{np.sqrt(cov_in[0, 0]):.2g}) rad/(m/s^2)")
    else:
        words += "; drive the circles slower (below 0.4 g) to measure it"
    return words


def _loglik(e: np.ndarray) -> float:
    var = max(float(np.mean(e ** 2)), 1e-300)
    return float(-0.5 * len(e) * (np.log(2 * np.pi * var) + 1))
