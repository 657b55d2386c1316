"""The Cramér-Rao lower bound of a model's parameters for given steering and noise.

For output error with stationary (coloured) measurement noise, the Fisher
information is a sum over DFT lines of the output sensitivities weighted by the
inverse noise spectrum (Whittle):

    I_ij = sum_k sum_o 2 Re( conj(dY_o,k/dtheta_i) dY_o,k/dtheta_j ) / (N S_o(f_k)),
    dY_o,k/dtheta = dH_o(f_k)/dtheta U_k

with U the DFT of the steer and S the per-sample noise spectrum (the one-sided PSD
times fs/2). Its inverse bounds the covariance of any unbiased estimator. Lines are
taken up to the prefilter's band (above it the data carry no information).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

F_MAX = 16.0  # Hz, inside the 20 Hz prefilter


def noise_psd_from_residuals(predictions, seg_s: float = 4.0):
    """One-sided PSD [unit^2/Hz] of each output's residual: {"ay": (f, P), "r": (f, P)}."""
    out = {}
    for j, o in enumerate(("ay", "r")):
        acc, w = None, 0
        for p in predictions:
            e = (p.y - p.yhat)[p.keep, j]
            fs = 1.0 / float(p.t[1] - p.t[0])
            f, P = signal.welch(e - e.mean(), fs=fs, nperseg=min(len(e), int(seg_s * fs)))
            acc = P * len(e) if acc is None else acc + np.interp(f, f, P) * len(e)
            w += len(e)
        out[o] = (f, acc / w)
    return out


def fisher_spectrum(model, p: dict, names: list, f: np.ndarray, U: np.ndarray, n: int, fs: float, vx: float,
                    noise: dict, f_max: float = F_MAX, rel_step: float = 1e-4) -> np.ndarray:
    """Fisher information from the steer's DFT U at the rfft frequencies f of an n-sample
    record (a measured record, or a planned manoeuvre's expected spectrum)."""
    k = len(names)
    band = (f > 0) & (f <= min(f_max, 0.45 * fs))
    fb = f[band]
    dY = np.zeros((k, 2, len(fb)), complex)
    for i, name in enumerate(names):
        h = rel_step * max(abs(p[name]), 1e-6)
        hp, hm = dict(p), dict(p)
        hp[name] += h
        hm[name] -= h
        dY[i] = (model.freqresp(hp, fb, vx) - model.freqresp(hm, fb, vx)) / (2 * h) * U[band]
    info = np.zeros((k, k))
    for o, out in enumerate(("ay", "r")):
        fn, Pn = noise[out]
        S = np.interp(fb, fn, Pn) * fs / 2.0
        D = dY[:, o, :]
        info += 2.0 * np.real(np.conj(D) @ (D / (n * S)).T)
    return info


def fisher(model, p: dict, names: list, inputs: list, noise: dict, f_max: float = F_MAX, rel_step: float = 1e-4):
    """Fisher information for ``names`` from input records [(steer, dt, vx), ...]."""
    info = np.zeros((len(names), len(names)))
    for steer, dt, vx in inputs:
        u = np.asarray(steer) - np.mean(steer)
        info += fisher_spectrum(model, p, names, np.fft.rfftfreq(len(u), dt), np.fft.rfft(u), len(u), 1.0 / dt,
                                vx, noise, f_max, rel_step)
    return info


def crlb(model, p: dict, names: list, inputs: list, noise: dict) -> np.ndarray:
    """Covariance bound (inverse Fisher information), physical units."""
    return np.linalg.pinv(fisher(model, p, names, inputs, noise))


def noise_psd_from_still(runs, seg_s: float = 1.0, f_prefilter: float = 20.0, target_fs: float = 200.0):
    """One-sided noise PSD of ay and r from the stand-still parts of the runs: sensor
    noise alone, with no dynamics and no model error in it. Signals get the same
    prefilter and rate as the fits. None when the runs never stand still."""
    from stid import segments
    from stid.fit.dataset import _decimate, prefilter

    acc = {"ay": [], "r": []}
    for run in runs:
        fs = run.fs
        q = max(1, int(round(fs / target_fs))) if fs > 1.5 * target_fs else 1
        mask = segments.still_mask(run.vx, fs)
        for a, b in segments.runs_of(mask, int(1.5 * seg_s * fs)):
            for name in ("ay", "r"):
                x = _decimate(prefilter(getattr(run, name)[a:b], fs, f_prefilter), q)
                x = x[len(x) // 8: len(x) - len(x) // 8]  # filter edges
                f, P = signal.welch(x - x.mean(), fs=fs / q, nperseg=min(len(x), int(seg_s * fs / q)))
                acc[name].append((f, P, len(x)))
    if not acc["ay"]:
        return None
    out = {}
    for name, parts in acc.items():
        f = parts[0][0]
        out[name] = (f, sum(np.interp(f, pf, P) * n for pf, P, n in parts) / sum(n for *_, n in parts))
    return out
