"""Time-domain fit of the nonlinear grey-box model (study 2) to runs with four
wheel speeds, lane changes and run-ups included (speed need not be constant)."""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from stid.errors import InputError
from stid.fit.dataset import filtered
from stid.fit.result import FitResult, Prediction, fit_percent
from stid.fit.solver import ParamSpace, covariance_sandwich, least_squares, to_physical
from stid.models.greybox import WHEELS, GreyBox

OUTPUTS = ("vx", "ay", "r")


def _pieces(runs, target_fs=100.0):
    out = []
    for run in runs:
        missing = [w for w in WHEELS if w not in run.extra]
        if missing:
            raise InputError(f"{run.name}: the grey-box model needs the wheel speeds {', '.join(WHEELS)} "
                             "[rad/s] (CSV columns); this run lacks " + ", ".join(missing))
        moving = np.flatnonzero(run.vx > 1.0)
        if len(moving) < 2 * run.fs:
            raise InputError(f"{run.name}: moving (vx > 1 m/s) for less than 2 s")
        q, sig, t = filtered(run, target_fs, ("steer", "ay", "r", "vx") + WHEELS)
        sl = slice(moving[0] // q, min(moving[-1] // q + 1, len(t)))
        out.append({"name": run.name, "t": t[sl], "steer": sig["steer"][sl],
                    "wheels": np.vstack([sig[w][sl] for w in WHEELS]),
                    "y": np.column_stack([sig["vx"][sl], sig["ay"][sl], sig["r"][sl]])})
    return out


def fit_greybox(runs, vehicle, discard_s: float = 0.3) -> FitResult:
    model = GreyBox(vehicle)
    pieces = _pieces(runs)
    keeps = [(pc["t"] - pc["t"][0]) >= discard_s for pc in pieces]

    bw = {"ay": float(vehicle.sensors.get("accel_bandwidth_hz", 50.0)),
          "r": float(vehicle.sensors.get("gyro_bandwidth_hz", 88.0))}

    def simulate(p, pc):
        y = pc["y"]
        out = model.simulate(p, pc["t"], pc["steer"], pc["wheels"], (y[0, 0], 0.0, y[0, 2]))
        fs = 1.0 / (pc["t"][1] - pc["t"][0])
        for col, name in ((1, "ay"), (2, "r")):  # the sensors' own low-pass, as in the linear models
            if 0 < bw[name] < float("inf") and np.all(np.isfinite(out[:, col])):
                b, a = signal.bilinear([2 * np.pi * bw[name]], [1, 2 * np.pi * bw[name]], fs)
                out[:, col] = signal.lfilter(b, a, out[:, col], zi=signal.lfilter_zi(b, a) * out[0, col])[0]
        return out

    def residual(p, sig):
        out = []
        for pc, k in zip(pieces, keeps):
            e = (simulate(p, pc)[k] - pc["y"][k]) / sig
            out.append(np.nan_to_num(e, nan=1e3).ravel())
        return np.concatenate(out)

    sigma = np.std(np.vstack([pc["y"][k] for pc, k in zip(pieces, keeps)]), axis=0)
    sigma = np.where(sigma > 0, sigma, 1.0)
    space = ParamSpace(model, model.param_names, {})
    res = least_squares(lambda p: residual(p, sigma), space, [model.defaults()])
    p_hat = space.to_p(res.x)
    sigma = np.std(residual(p_hat, np.ones(3)).reshape(-1, 3), axis=0)
    sigma = np.where(sigma > 0, sigma, 1.0)
    res = least_squares(lambda p: residual(p, sigma), space, [p_hat])
    p_hat = space.to_p(res.x)
    J_blocks, r_blocks, pos = [], [], 0
    for k in keeps:
        m = int(k.sum()) * 3
        J_blocks.append(res.jac[pos:pos + m].reshape(-1, 3, len(space.free)))
        r_blocks.append(res.fun[pos:pos + m].reshape(-1, 3))
        pos += m
    cov = to_physical(covariance_sandwich(J_blocks, r_blocks), space, res.x)
    names = list(space.free)
    result = FitResult(model="greybox", method="time (nonlinear grey-box)", names=names,
                       values=np.array([p_hat[n] for n in names]), cov=cov,
                       units={n: model.param(n).unit for n in names}, owners={n: "greybox" for n in names})
    yh = [simulate(p_hat, pc) for pc in pieces]
    Y = np.vstack([pc["y"][k] for pc, k in zip(pieces, keeps)])
    YH = np.vstack([h[k] for h, k in zip(yh, keeps)])
    result.fit = {o: fit_percent(Y[:, i], YH[:, i]) for i, o in enumerate(OUTPUTS)}
    e = Y - YH
    var = np.maximum(np.mean(e ** 2, axis=0), 1e-300)
    result.n = e.size
    result.loglik = float(-0.5 * len(e) * np.sum(np.log(2 * math.pi * var) + 1))
    result.predictions = [Prediction(pc["name"], pc["t"], pc["steer"], pc["y"][:, 1:], h[:, 1:],
                                     float(np.median(pc["y"][:, 0])), k) for pc, h, k in zip(pieces, yh, keeps)]
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
    slips = np.concatenate([np.abs(pc["wheels"][2] * vehicle.wheel_radius / np.maximum(pc["y"][:, 0], 0.5) - 1)
                            for pc in pieces])
    if np.percentile(slips, 95) < 0.005:
        result.warn("the wheels barely slip (95% of slips below 0.5%): Cx is poorly determined; "
                    "include accelerating or braking")
    return result
