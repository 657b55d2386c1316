"""The noise floor: the best fit percent a linear model driven by the measured steer
(at the measured speed) can reach on this data, so the user knows when to stop adding
effects.

It is estimated without any vehicle model: a long FIR predictor (1 s of steer
history and a constant) is fitted by least squares to one half of each stretch and
scored on the other, and vice versa (two-fold cross-validation keeps it from
counting noise as signal). What it cannot predict (noise, vibration, and
nonlinearity) no linear model can. A nonlinear effect can beat this linear floor
slightly. (Coherence would say the same in principle, but Welch coherence is
biased low by response delays and leakage, and the floor came out below fits
actually reached.)

On a track run the speed swings, and one impulse response cannot follow the car
through it: the predictor's taps then vary with the speed, h_j(v) = h0_j + h1_j d +
h2_j d^2 with d = v/median(v) - 1 taken at the output's time (the frozen-speed
response, which is what a slowly varying car has). Samples lost on the link are
neither trained on nor scored."""

from __future__ import annotations

import numpy as np
from scipy.linalg import toeplitz

MEMORY_S = 1.0


def _design(u: np.ndarray, taps: int) -> np.ndarray:
    col = u
    row = np.zeros(taps)
    row[0] = u[0]
    X = toeplitz(col, row)
    return np.column_stack([X, np.ones(len(u))])


SPEED_VARIES = 0.03  # relative speed spread (10-90%) above which the taps follow the speed


def _fir_cv(u: np.ndarray, y: np.ndarray, taps: int, ridge: float = 1e-6, vx=None, valid=None) -> np.ndarray:
    """Two-fold cross-validated FIR prediction of y from u (prediction for every sample)."""
    X = _design(u - u.mean(), taps)
    if vx is not None:
        d = np.asarray(vx, float) / np.median(vx) - 1.0
        if np.percentile(d, 90) - np.percentile(d, 10) > SPEED_VARIES:
            fir = X[:, :-1]
            X = np.column_stack([fir, fir * d[:, None], fir * (d * d)[:, None], X[:, -1:]])
    n = len(u)
    ok = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    half = n // 2
    pred = np.empty(n)
    for tr, te in ((slice(taps, half), slice(half, n)), (slice(half + taps, n), slice(0, half))):
        A, b = X[tr][ok[tr]], y[tr][ok[tr]]
        reg = ridge * np.trace(A.T @ A) / A.shape[1] * np.eye(A.shape[1])
        w = np.linalg.solve(A.T @ A + reg, A.T @ b)
        pred[te] = X[te] @ w
    return pred


def floor_errors(stretches, memory_s: float = MEMORY_S, keep_from_s: float = 0.5) -> tuple[dict, dict]:
    """The FIR predictor's cross-validated errors (the floor, sample by sample) and the
    outputs they belong to, per output: lists of arrays, one per stretch."""
    err = {"ay": [], "r": []}
    ref = {"ay": [], "r": []}
    for st in stretches:
        taps = max(5, int(memory_s / st.dt))
        if len(st.steer) < 6 * taps:
            continue
        keep = (st.t - st.t[0]) >= max(keep_from_s, memory_s)
        valid = getattr(st, "valid", None)
        if valid is not None:
            keep = keep & valid
        for name, y in (("ay", st.ay), ("r", st.r)):
            pred = _fir_cv(st.steer, y, taps, vx=getattr(st, "vx_series", None), valid=valid)
            err[name].append((y - pred)[keep])
            ref[name].append(y[keep])
    return err, ref


def noise_floor(stretches, memory_s: float = MEMORY_S, keep_from_s: float = 0.5) -> dict:
    err, ref = floor_errors(stretches, memory_s, keep_from_s)
    out = {}
    for k in err:
        if not err[k]:
            out[k] = float("nan")
            continue
        e = np.concatenate(err[k])
        y = np.concatenate(ref[k])
        out[k] = float(100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean())))
    return out
