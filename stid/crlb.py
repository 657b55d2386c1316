"""The Cramér-Rao lower bound of a model's parameters for given steering and noise.

For output error with stationary (coloured) measurement noise, the Fisher
information is a sum over DFT lines of the output sensitivities weighted by the
inverse noise spectrum (Whittle):

    I_ij = sum_k sum_o 2 Re( conj(dY_o,k/dtheta_i) dY_o,k/dtheta_j ) / (N S_o(f_k)),
    dY_o,k/dtheta = dH_o(f_k)/dtheta U_k

with U the DFT of the steer and S the per-sample noise spectrum (the one-sided PSD
times fs/2). Its inverse bounds the covariance of any unbiased estimator. Lines are
taken up to the prefilter's band (above it the data carry no information).

The bound is what an efficient estimator (one that whitens the noise's colour) would
reach. ``stid fit`` ships an output-error fit with one weight per output, which does not
whiten: for coloured noise its covariance is the sandwich A^-1 B A^-1 with
A = sum w_o 2 Re(D D^H) / n and B = sum w_o^2 2 Re(D S_o D^H) / n (``oe_covariance``),
equal to the bound when the noise is white. When the model is not exactly the system,
the residual (model error + noise) is what the fit sees as noise: its spectrum
(``noise_psd_from_residuals``) in place of the stand-still's gives the spread the fit
shows on data from that system, not merely the spread sensor noise alone would cause.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

F_MAX = 16.0  # Hz, inside the 20 Hz prefilter


def residual_model(predictions, seg_s: float = 4.0) -> dict:
    """What a fit's residual is made of, per output, as the plan needs it:

    - ``"ay"``, ``"r"``: (f, P), the one-sided PSD of the residual's part *incoherent* with
      the steer (sensor noise, and model error that is not a linear response to the steer):
      it spreads the estimates as noise does;
    - ``"model_error"``: {output: (f, G)}, the residual's linear response to the steer
      G = S_eu / S_uu (H1): model error that moves with the steer. Its mean effect on the
      fit is a bias no data can show; from one random input to the next it moves the
      estimates too, by how much the steer's power at each line varies (oe_terms);
    - ``"variance"``: {output: var}, the residual's whole variance (the fit's weights);
    - ``"follows_steer"``: {output: share}, the part of the residual's power that is a linear
      response to the steer, less what chance gives an estimate from this many segments (the
      squared coherence of independent signals averages 1 / segments: 6-8% on a right model
      with white noise, read as model error).

    The segments keep their low frequencies: each stretch loses only its own mean, not each 4 s
    segment's. A segment's mean is the noise's power below 1/seg_s, which a fit meets as much as
    any (a drifting gyro, 0.003 rad/s/sqrt(s): the plan from the residual of a run predicted
    0.57-0.70 of the spread of Cf and Iz over 30 seeds with each segment's mean taken off, and
    0.67-1.01 without; white and coloured noise moved by 0-3%).
    """
    out = {"model_error": {}, "variance": {}, "follows_steer": {}}
    for j, o in enumerate(("ay", "r")):
        f0, acc_p, acc_c, acc_u, w, var = None, None, None, None, 0, 0.0
        weights, segments = [], []
        for p in predictions:
            e = (p.y - p.yhat)[p.keep, j]
            u = np.asarray(p.steer)[p.keep]
            fs = 1.0 / float(p.t[1] - p.t[0])
            nper = min(len(e), int(seg_s * fs))
            e, u = e - e.mean(), u - u.mean()
            f, Pee = signal.welch(e, fs=fs, nperseg=nper, detrend=False)
            _, Puu = signal.welch(u, fs=fs, nperseg=nper, detrend=False)
            _, Peu = signal.csd(u, e, fs=fs, nperseg=nper, detrend=False)
            if f0 is None:
                f0, acc_p, acc_u, acc_c = f, Pee * len(e), Puu * len(e), Peu * len(e)
            else:
                acc_p = acc_p + np.interp(f0, f, Pee) * len(e)
                acc_u = acc_u + np.interp(f0, f, Puu) * len(e)
                acc_c = acc_c + (np.interp(f0, f, Peu.real) + 1j * np.interp(f0, f, Peu.imag)) * len(e)
            w += len(e)
            var += float(np.sum(e ** 2))
            weights.append(len(e))
            # Hann segments overlapping by half: each counts as 1 / 1.056 of an independent one
            segments.append(max((len(e) - nper) // max(nper // 2, 1) + 1, 1) / (1.056 if len(e) > nper else 1.0))
        Pee, Puu, Peu = acc_p / w, acc_u / w, acc_c / w
        ok = Puu > 1e-12 * max(Puu.max(), 1e-300)
        G = np.where(ok, Peu / np.where(ok, Puu, 1.0), 0.0)
        coherent = np.abs(G) ** 2 * Puu
        out[o] = (f0, np.maximum(Pee - coherent, 1e-3 * Pee))
        out["model_error"][o] = (f0, G)
        out["variance"][o] = var / w
        k = float(sum(weights) ** 2 / sum(wi * wi / si for wi, si in zip(weights, segments)))  # segments pooled
        share = float(np.sum(coherent) / max(float(np.sum(Pee)), 1e-300))
        out["follows_steer"][o] = max((k * share - 1.0) / (k - 1.0), 0.0) if k > 1 else share
    return out


def noise_psd_from_residuals(predictions, seg_s: float = 4.0):
    """One-sided PSD [unit^2/Hz] of each output's residual: {"ay": (f, P), "r": (f, P)}."""
    out = {}
    for j, o in enumerate(("ay", "r")):
        f0, acc, w = None, None, 0
        for p in predictions:
            e = (p.y - p.yhat)[p.keep, j]
            fs = 1.0 / float(p.t[1] - p.t[0])
            f, P = signal.welch(e - e.mean(), fs=fs, nperseg=min(len(e), int(seg_s * fs)))
            if f0 is None:
                f0, acc = f, P * len(e)
            else:  # stretches of other rates or lengths: onto the first one's lines
                acc = acc + np.interp(f0, f, P) * len(e)
            w += len(e)
        out[o] = (f0, acc / w)
    return out


def _sensitivities(model, p, names, fb, U, vx, sensors, rel_step):
    dY = np.zeros((len(names), 2, len(fb)), complex)
    for i, name in enumerate(names):
        h = rel_step * max(abs(p[name]), 1e-6)
        hp, hm = dict(p), dict(p)
        hp[name] += h
        hm[name] -= h
        dY[i] = (model.freqresp(hp, fb, vx, sensors) - model.freqresp(hm, fb, vx, sensors)) / (2 * h) * U
    return dY


def _band(f, fs, f_max):
    return (f > 0) & (f <= min(f_max, 0.45 * fs))


def fisher_spectrum(model, p: dict, names: list, f: np.ndarray, U: np.ndarray, n: int, fs: float, vx: float,
                    noise: dict, f_max: float = F_MAX, rel_step: float = 1e-4, sensors: dict | None = None
                    ) -> np.ndarray:
    """Fisher information from the steer's DFT U at the rfft frequencies f of an n-sample
    record (a measured record, or a planned manoeuvre's expected spectrum). ``sensors``:
    the data's sensor chain (default the model's)."""
    band = _band(f, fs, f_max)
    fb = f[band]
    dY = _sensitivities(model, p, names, fb, U[band], vx, sensors, rel_step)
    info = np.zeros((len(names), len(names)))
    for o, out in enumerate(("ay", "r")):
        fn, Pn = noise[out]
        S = np.interp(fb, fn, Pn) * fs / 2.0
        D = dY[:, o, :]
        info += 2.0 * np.real(np.conj(D) @ (D / (n * S)).T)
    return info


def oe_terms(model, p: dict, names: list, f: np.ndarray, U: np.ndarray, n: int, fs: float, vx: float,
             noise: dict, f_max: float = F_MAX, rel_step: float = 1e-4, sensors: dict | None = None):
    """(A, B, Fisher information) for one record: A^-1 B A^-1 is the covariance of the
    output-error fit, each output weighted by the inverse of its total noise variance (as
    ``stid fit`` does: one weight per output, no whitening). Sum over records first."""
    band = _band(f, fs, f_max)
    fb = f[band]
    dY = _sensitivities(model, p, names, fb, U[band], vx, sensors, rel_step)
    k = len(names)
    A, B, info = np.zeros((k, k)), np.zeros((k, k)), np.zeros((k, k))
    me = noise.get("model_error") or {}
    c = np.zeros((k, len(fb)))
    for o, out in enumerate(("ay", "r")):
        fn, Pn = noise[out]
        var = (noise.get("variance") or {}).get(out)
        w = 1.0 / max(float(var if var is not None else np.trapezoid(Pn, fn)), 1e-300)
        S = np.interp(fb, fn, Pn) * fs / 2.0
        D = dY[:, o, :]
        A += w * 2.0 * np.real(np.conj(D) @ D.T) / n
        B += w * w * 2.0 * np.real(np.conj(D) @ (D * S).T) / n
        info += 2.0 * np.real(np.conj(D) @ (D / (n * S)).T)
        if out in me:
            # model error e = G u: the fit's gradient gets sum_k Re(conj(dH) G) |U_k|^2, whose mean
            # is the bias and whose spread follows var|U_k|^2 = |U_k|^4 (Gaussian steer)
            fg, G = me[out]
            Gb = np.interp(fb, fg, G.real) + 1j * np.interp(fb, fg, G.imag)
            Ub = U[band]
            dH = D / np.where(Ub != 0, Ub, 1.0)
            c += w * np.real(np.conj(dH) * Gb)
    if me:
        P2 = np.abs(U[band]) ** 4
        B += (2.0 / n) ** 2 * (c * P2) @ c.T
    return A, B, info


def sandwich(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    Ai = np.linalg.pinv(A)
    return Ai @ B @ Ai


def _records(inputs):
    for rec in inputs:
        steer, dt, vx = rec[:3]
        sensors = rec[3] if len(rec) > 3 else None
        u = np.asarray(steer) - np.mean(steer)
        yield np.fft.rfftfreq(len(u), dt), np.fft.rfft(u), len(u), 1.0 / dt, float(np.mean(vx)), sensors


def fisher(model, p: dict, names: list, inputs: list, noise: dict, f_max: float = F_MAX, rel_step: float = 1e-4):
    """Fisher information for ``names`` from input records [(steer, dt, vx[, sensors]), ...]
    (a varying speed enters by its mean: the bound is for the linearisation there)."""
    info = np.zeros((len(names), len(names)))
    for f, U, n, fs, vx, sensors in _records(inputs):
        info += fisher_spectrum(model, p, names, f, U, n, fs, vx, noise, f_max, rel_step, sensors)
    return info


def crlb(model, p: dict, names: list, inputs: list, noise: dict) -> np.ndarray:
    """Covariance bound (inverse Fisher information), physical units."""
    return np.linalg.pinv(fisher(model, p, names, inputs, noise))


def oe_covariance(model, p: dict, names: list, inputs: list, noise: dict, f_max: float = F_MAX,
                  rel_step: float = 1e-4) -> np.ndarray:
    """Covariance of the output-error fit ``stid fit`` ships, for noise of the given
    spectrum (the bound itself when the noise is white), physical units."""
    k = len(names)
    A, B = np.zeros((k, k)), np.zeros((k, k))
    for f, U, n, fs, vx, sensors in _records(inputs):
        a, b, _ = oe_terms(model, p, names, f, U, n, fs, vx, noise, f_max, rel_step, sensors)
        A += a
        B += b
    return sandwich(A, B)


def noise_psd_from_still(runs, seg_s: float = 1.0, f_prefilter: float = 20.0, target_fs: float = 200.0):
    """One-sided noise PSD of ay and r from the stand-still parts of the runs: sensor
    noise alone, with no dynamics and no model error in it. Signals get the same
    prefilter and rate as the fits. None when the runs never stand still."""
    from stid import segments
    from stid.fit.dataset import _decimate, decimation, prefilter

    acc = {"ay": [], "r": []}
    for run in runs:
        fs = run.fs
        q = decimation(fs, target_fs)
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
