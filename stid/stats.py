"""Statistics shared by the fitting code and the analysis of its results: correlation
of time series and how long it lasts. Both sides import it from here, so the analysis
does not reach into the fitting code's internals."""

from __future__ import annotations

import numpy as np

# Fit percent is scored from this far into each stretch, everywhere (fit, compare, diagnose,
# report) and for the noise floor alike: the floor's predictor needs 1 s of steer history, and
# a model and its floor are only comparable on the same samples. (The cost a fit minimises
# starts earlier, at 0.5 s, once the unknown initial state has died out.)
SCORE_FROM_S = 1.0


def autocorrelation(e: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation of e at lags 0..max_lag (FFT)."""
    e = e - e.mean()
    n = len(e)
    if n < 4 or not np.any(e):
        out = np.zeros(max_lag + 1)
        out[0] = 1.0
        return out
    # zero-padded to a power of two: at 2n a length with a large prime factor (n = 57,924
    # samples) took numpy 85-100 ms, not 3. n + max_lag of them keep the lags returned linear
    # (a circular lag k wraps onto k - m, beyond the series when m >= n + k): half the length
    # 2n - 1 would need, for the few lags the callers ask
    m = 1 << int(np.ceil(np.log2(n + min(max_lag, n - 1))))
    f = np.fft.rfft(e, m)
    ac = np.fft.irfft(f * np.conj(f), m)[: max_lag + 1]
    return ac / ac[0]


def autocorr_length(e: np.ndarray, max_lag: int) -> int:
    """Lag at which the autocorrelation first falls below 0.05."""
    below = np.flatnonzero(np.abs(autocorrelation(e, max_lag)) < 0.05)
    return int(below[0]) if len(below) else max_lag


def xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation r_ab(k) = E[a(t) b(t-k)] for k = -max_lag..max_lag (FFT;
    numpy's, as scipy.signal costs most of a second to import)."""
    a = a - a.mean()
    b = b - b.mean()
    n = len(a)
    m = 1 << int(np.ceil(np.log2(2 * n - 1)))
    full = np.fft.irfft(np.fft.rfft(a, m) * np.conj(np.fft.rfft(b, m)), m)
    lags = np.arange(-max_lag, max_lag + 1)
    return full[lags % m] / (n * np.std(a) * np.std(b) + 1e-300)


def tau_int(e: np.ndarray, max_lag: int) -> float:
    """Integrated autocorrelation time 1 + 2 sum rho_k [samples], summed until rho first
    drops below 0.05."""
    if len(e) < 8 or not np.any(e - e.mean()):
        return 1.0
    ac = autocorrelation(e, max_lag)
    below = np.flatnonzero(ac[1:] < 0.05)
    k = int(below[0]) + 1 if len(below) else max_lag
    return float(max(1.0, 1 + 2 * np.sum(ac[1:k])))


def tau_int_blocks(blocks, max_lag: int) -> np.ndarray:
    """tau_int of each column over blocks (n_i, k) of one series cut in pieces (the stretches
    of a fit), averaged by length; blocks of 2 max_lag samples or fewer are left out (0 where
    none is longer)."""
    taus, n_tot = None, 0
    for b in blocks:
        b = np.asarray(b, float)
        if len(b) <= 2 * max_lag:
            continue
        t = np.array([tau_int(b[:, j], max_lag) for j in range(b.shape[1])])
        taus = len(b) * t if taus is None else taus + len(b) * t
        n_tot += len(b)
    if taus is None:
        return np.zeros(np.shape(blocks[0])[1] if len(blocks) else 0)
    return taus / n_tot
