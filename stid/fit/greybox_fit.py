"""Time-domain fit of the nonlinear grey-box model (study 2) to runs with four
wheel speeds, lane changes and run-ups included (speed need not be constant).

``greybox`` fits Cx, Cyf, Cyr (per axle), Iz (and air drag CA). ``greybox-study``
fits the study's single Cy and then checks it against a per-axle fit on the same
data: when the two axles differ measurably, one Cy cannot represent the car and
the study's Cy and Iz are biased, which the result says in one warning.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import signal

from stid import sensor_chain
from stid.errors import InputError
from stid.fit import convergence
from stid.fit.dataset import filtered
from stid.fit.result import FitResult, Prediction, fit_percent
from stid.fit.solver import ParamSpace, covariance_sandwich, least_squares, to_physical
from stid.models.greybox import MODEL_NAMES, WHEELS, GreyBox

OUTPUTS = ("vx", "ay", "r")
# A parameter whose 95% interval is wider than this fraction of its value either way
# is called poorly determined (the user is told what to drive to pin it down).
POOR_HALF_WIDTH = 0.06
# The per-axle check of greybox-study: |Cyf - Cyr| beyond this many (robust)
# standard errors means one Cy cannot represent the car.
ONE_CY_Z = 3.0
SLIP_MIN = 0.005  # rear slip below which Cx has nothing to go on ...
SLIP_MIN_S = 0.5  # s ... and how long the runs must slip more than that
END_TRIM_S = 0.1  # s


def _pieces(runs, target_fs=100.0):
    out, still = [], []
    for run in runs:
        missing = [w for w in WHEELS if w not in run.extra]
        if missing:
            raise InputError(f"{run.name}: the grey-box model needs the wheel speeds {', '.join(WHEELS)} "
                             "[rad/s]; this run lacks " + ", ".join(missing) + ". Log with four hall sensors "
                             "(firmware WHEELS = 4; stid-sim --wheel-speeds) or give them as CSV columns")
        moving = np.flatnonzero(run.vx > 1.0)
        if len(moving) < 2 * run.fs:  # (a piece a gap cut off a run's start: the others are fitted)
            still.append(run.name)
            continue
        q, sig, t = filtered(_unheld(run), target_fs, ("steer", "ay", "r", "vx") + WHEELS)
        # a run that ends at speed ends in the decimating filter's edge ringing: leave it out
        tail = int(math.ceil(END_TRIM_S * run.fs / q))
        sl = slice(moving[0] // q, min(moving[-1] // q + 1, len(t) - tail))
        valid = np.asarray(sig.get("valid", np.ones(len(t), bool)), bool)[sl]
        out.append({"name": run.name, "t": t[sl], "steer": sig["steer"][sl],
                    "wheels": np.vstack([sig[w][sl] for w in WHEELS]),
                    "y": np.column_stack([sig["vx"][sl], sig["ay"][sl], sig["r"][sl]]), "valid": valid,
                    "sensors": run.meta.get("sensor_chain")})
    if not out:
        raise InputError(f"{', '.join(still)}: moving (vx > 1 m/s) for less than 2 s")
    return out, still


def unhold(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A wheel speed by the edge-period method (held from one hall edge to the next, each
    value the mean speed over the interval that ended at its edge) as a signal without
    that delay: each value placed at its interval's midpoint, linear in between.

    Held, the speed lags by one to one and a half edge periods (70 ms at 4 m/s with one
    magnet per wheel), differently on each wheel: the slip from the difference of two
    such wheels is wrong by acceleration x lag difference / speed, as large as the slip
    itself. ``x`` that is not held (fewer than half its samples repeat) is returned as is:
    stid's own loader centres the speeds at the exact edge times already
    (``host.units.wheel_speeds(centred=True)``); this is for CSVs from loggers that hold.
    """
    x = np.asarray(x, float)
    new = np.flatnonzero(np.diff(x) != 0) + 1  # samples where a new value arrived
    if len(new) < 3 or np.mean(np.diff(x) == 0) < 0.5:
        return x
    dt = float(np.median(np.diff(t)))
    edge = t[new] - 0.5 * dt  # the edge fell within the sample period before
    mid = 0.5 * (edge[:-1] + edge[1:])
    out = np.interp(t, mid, x[new[1:]])
    out[: new[1]] = x[: new[1]]  # before the second edge there is no interval to place
    return out


def _unheld(run):
    """The run with its wheel speeds (and vx, when it is the front wheels' mean) unheld."""
    w = {k: unhold(run.t, run.extra[k]) for k in WHEELS}
    vx = run.vx
    fronts = 0.5 * (run.extra["w_fl"] + run.extra["w_fr"])
    ratio = np.median(vx[vx > 1.0] / np.maximum(fronts[vx > 1.0], 1e-9)) if np.any(vx > 1.0) else float("nan")
    if np.isfinite(ratio) and np.allclose(vx, ratio * fronts, rtol=1e-3, atol=1e-3):
        # vx is the free-rolling front wheels' mean speed (the simulator's and a 4-hall car's)
        vx = ratio * 0.5 * (w["w_fl"] + w["w_fr"])
    else:
        vx = unhold(run.t, vx)
    return dataclasses.replace(run, vx=vx, extra={**run.extra, **w})


class _Problem:
    """The output-error cost of one grey-box form on a set of pieces."""

    def __init__(self, model: GreyBox, pieces, vehicle, discard_s: float):
        self.model, self.pieces = model, pieces
        # the start-up transient of the simulation, and samples a lost frame reaches
        self.keeps = [((pc["t"] - pc["t"][0]) >= discard_s) & pc["valid"] for pc in pieces]
        self.filters = []  # the sensors' own low-pass, as in the linear models (stid.sensor_chain)
        for pc in pieces:
            chain = pc.get("sensors") or sensor_chain.from_vehicle(vehicle)
            bw = {1: float(chain.get("ay", 0.0) or 0.0), 2: float(chain.get("r", 0.0) or 0.0)}
            fs = 1.0 / (pc["t"][1] - pc["t"][0])
            order = {1: sensor_chain.order(chain, "ay"), 2: sensor_chain.order(chain, "r")}
            self.filters.append({col: (signal.butter(2, f, fs=fs) if order[col] == 2 else
                                       signal.bilinear([2 * np.pi * f], [1, 2 * np.pi * f], fs))
                                 for col, f in bw.items() if 0 < f < float("inf")})

    def simulate(self, p, i):
        pc = self.pieces[i]
        y = pc["y"]
        out = self.model.simulate(p, pc["t"], pc["steer"], pc["wheels"], (y[0, 0], 0.0, y[0, 2]))
        for col, (b, a) in self.filters[i].items():
            if np.all(np.isfinite(out[:, col])):
                out[:, col] = signal.lfilter(b, a, out[:, col], zi=signal.lfilter_zi(b, a) * out[0, col])[0]
        return out

    def residual(self, p, sig):
        out = []
        for i, (pc, k) in enumerate(zip(self.pieces, self.keeps)):
            e = (self.simulate(p, i)[k] - pc["y"][k]) / sig
            out.append(np.nan_to_num(e, nan=1e3).ravel())
        return np.concatenate(out)

    def measured(self):
        return np.vstack([pc["y"][k] for pc, k in zip(self.pieces, self.keeps)])

    def fit(self, start: dict):
        """Two passes: weights from the outputs' spread, then from the first fit's residuals
        (each output then counts by how well the model can follow it)."""
        model = self.model
        sigma = np.std(self.measured(), axis=0)
        sigma = np.where(sigma > 0, sigma, 1.0)
        space = ParamSpace(model, model.param_names, {})
        res = least_squares(lambda p: self.residual(p, sigma), space, [start])
        p_hat = space.to_p(res.x)
        sigma = np.std(self.residual(p_hat, np.ones(3)).reshape(-1, 3), axis=0)
        sigma = np.where(sigma > 0, sigma, 1.0)
        res = least_squares(lambda p: self.residual(p, sigma), space, [p_hat])
        J_blocks, r_blocks, pos = [], [], 0
        for k in self.keeps:
            m = int(k.sum()) * 3
            J_blocks.append(res.jac[pos:pos + m].reshape(-1, 3, len(space.free)))
            r_blocks.append(res.fun[pos:pos + m].reshape(-1, 3))
            pos += m
        cov = to_physical(covariance_sandwich(J_blocks, r_blocks), space, res.x)
        return space, res, space.to_p(res.x), cov


def fit_greybox(runs, vehicle, form: str = "greybox", discard_s: float = 0.3) -> FitResult:
    """Fit the grey-box ``form`` (``greybox`` per axle, ``greybox-study`` one Cy) to runs
    with the four wheel speeds; warnings name what the data cannot determine."""
    if form not in MODEL_NAMES:
        raise InputError(f"unknown grey-box model {form!r}; choose one of {', '.join(MODEL_NAMES)}")
    pieces, still = _pieces(runs)
    model = GreyBox(vehicle, form)
    prob = _Problem(model, pieces, vehicle, discard_s)
    space, res, p_hat, cov = prob.fit(model.defaults())
    result = _result(prob, space, res, p_hat, cov)
    # (a simulation that diverged gives nan, which the cost saw as a large constant)
    settled = all(np.all(np.isfinite(pr.yhat)) for pr in result.predictions)
    result.set_verdict(convergence.judge(res, space, simulation_settled=settled))
    result.interval = "95% intervals: noise only (robust covariance of the output-error fit)"
    if still:
        result.note(f"{', '.join(still)}: moving (vx > 1 m/s) for less than 2 s: left out")
    for chain in sorted({sensor_chain.describe(pc.get("sensors") or sensor_chain.from_vehicle(vehicle))
                         for pc in pieces}):
        result.note(chain)
    for w in sensor_chain.undeclared_warnings(runs, vehicle):
        result.warn(w)
    biased = form == "greybox-study" and _check_one_cy(result, pieces, vehicle, discard_s, p_hat)
    # (a biased fit's intervals say nothing about what to drive: the model is the problem)
    _warn_poorly_determined(result, pieces, vehicle, lateral=not biased)
    return result


def _result(prob: _Problem, space, res, p_hat, cov) -> FitResult:
    model = prob.model
    names = list(space.free)
    result = FitResult(model=model.name, method="time (nonlinear grey-box)", names=names,
                       values=np.array([p_hat[n] for n in names]), cov=cov,
                       units={n: model.param(n).unit for n in names}, owners={n: "greybox" for n in names},
                       positive=tuple(n for n in names if getattr(model.param(n), "log", False)))
    yh = [prob.simulate(p_hat, i) for i in range(len(prob.pieces))]
    Y = prob.measured()
    YH = np.vstack([h[k] for h, k in zip(yh, prob.keeps)])
    result.fit = {o: fit_percent(Y[:, i], YH[:, i]) for i, o in enumerate(OUTPUTS)}
    e = Y - YH
    var = np.maximum(np.mean(e ** 2, axis=0), 1e-300)
    result.n = e.size
    result.loglik = float(-0.5 * len(e) * np.sum(np.log(2 * math.pi * var) + 1))
    result.predictions = [Prediction(pc["name"], pc["t"], pc["steer"], pc["y"][:, 1:], h[:, 1:],
                                     float(np.median(pc["y"][:, 0])), k)
                          for pc, h, k in zip(prob.pieces, yh, prob.keeps)]
    for n in space.at_bound(res.x):
        # a value pinned at a bound has no meaningful standard error: report it as such
        i = result.names.index(n)
        keep = [j for j in range(len(result.names)) if j != i]
        result.fixed[n] = (p_hat[n], model.param(n).unit, "at its bound")
        result.names = [result.names[j] for j in keep]
        result.values = result.values[keep]
        result.cov = result.cov[np.ix_(keep, keep)]
        if n != "CA":
            result.warn(f"{n} stopped at its bound ({p_hat[n]:.4g} {model.param(n).unit})")
    if not model.per_axle and "Cy" in result.names:
        # DESIGN: cornering stiffness is reported per axle; the study's Cy is per tyre
        se = 2 * result.stderr[result.names.index("Cy")]
        result.fixed["Cy_axle"] = (2 * p_hat["Cy"], "N/rad per axle", f"= 2 Cy, per axle (std. error {se:.4g})")
    return result


def _check_one_cy(result: FitResult, pieces, vehicle, discard_s: float, p_study: dict) -> bool:
    """Fit the per-axle form on the same data, from the study's optimum; a Wald test on
    Cyf - Cyr (robust covariance) says whether one Cy can represent the car."""
    axle = GreyBox(vehicle, "greybox")
    prob = _Problem(axle, pieces, vehicle, discard_s)
    start = {k: v for k, v in p_study.items() if k != "Cy"}
    start["Cyf"] = start["Cyr"] = 2 * p_study["Cy"]
    space, res, p, cov = prob.fit(start)
    i, j = space.free.index("Cyf"), space.free.index("Cyr")
    d = p["Cyf"] - p["Cyr"]
    se = math.sqrt(max(cov[i, i] + cov[j, j] - 2 * cov[i, j], 1e-300))
    z = abs(d) / se
    result.extra["per_axle"] = {"Cyf": p["Cyf"], "Cyr": p["Cyr"], "Iz": p["Iz"], "Cx": p["Cx"], "z": z}
    if z > ONE_CY_Z:
        result.warn(f"one Cy cannot represent this car: a per-axle fit on the same data gives Cyf {p['Cyf']:.4g} "
                    f"and Cyr {p['Cyr']:.4g} N/rad per axle ({z:.0f} standard errors apart) and Iz "
                    f"{p['Iz']:.3g} kg m^2, so this fit's Cy ({2 * p_study['Cy']:.4g} N/rad per axle) and Iz "
                    f"({p_study['Iz']:.3g} kg m^2) are biased: use --model greybox")
        return True
    return False


def _warn_poorly_determined(result: FitResult, pieces, vehicle, lateral: bool = True) -> None:
    """Name each parameter whose 95% interval is wide, with the manoeuvre that would pin it."""
    # (the interval alone cannot say it: without slip, Cx only ties the speed to the wheels,
    # and its Jacobian still looks informative)
    slipping = sum(float(np.sum(np.abs((pc["wheels"][2] + pc["wheels"][3]) * vehicle.wheel_radius
                                       / (2 * np.maximum(pc["y"][:, 0], 0.5)) - 1) > SLIP_MIN))
                   * float(pc["t"][1] - pc["t"][0]) for pc in pieces)
    weak_slip = slipping < SLIP_MIN_S
    if weak_slip:
        result.warn(f"the driven wheels barely slip (rear slip above {100 * SLIP_MIN:g}% for {slipping:.1f} s): "
                    "Cx is poorly determined; include a hard acceleration or braking")
    weak = []
    for name, half, (lo, hi) in zip(result.names, result.half95, result.ci95):
        v = result.value(name)
        if name == "CA" or not v or not np.isfinite(half) or half <= POOR_HALF_WIDTH * abs(v):
            continue
        if name == "Cx":
            if not weak_slip:
                result.warn(f"Cx is poorly determined (95% interval {lo:.4g} to {hi:.4g}): the runs hold too "
                            "little wheel slip; add a hard acceleration or braking from speed")
        elif lateral:
            weak.append(f"{name} ({lo:.4g} to {hi:.4g})")
    if weak:
        result.warn("poorly determined (95% interval): " + ", ".join(weak) + "; the steering is too slow or "
                    "too gentle for the yaw dynamics: add a quicker lane change, a higher speed, or a "
                    "random-steer or step-steer run at constant speed")
