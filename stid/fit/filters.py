"""The two filters every fit's data go through, without importing scipy.signal.

The prefilter is scipy.signal's ``sosfiltfilt(butter(4, f, fs=fs, output="sos"), x)``
and the decimation is ``decimate(x, q, ftype="fir", zero_phase=True)``: the same
designs, the same edge handling, the same numbers to rounding (tests/test_filters.py
compares them with scipy.signal). They are written here because ``import scipy.signal``
costs 0.55 s (scipy 1.17 parses the docstring of every function it exports, and
pulls in scipy.stats): a third of the whole ``stid diagnose`` command on a short
run. Commands that need more of scipy.signal (frequency responses, reports, the
planner) import it where they use it.

The IIR part needs no compiled loop of its own: a difference equation is a banded
lower-triangular system (unit diagonal, the denominator below it), which LAPACK's
triangular band solver (``dtbtrs``) solves by forward substitution, the filter's
own recursion.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


def butter_lowpass_sos(order: int, f_hz: float, fs: float) -> np.ndarray:
    """Second-order sections of a digital Butterworth low-pass (even ``order``), as
    scipy.signal.butter(order, f_hz, fs=fs, output="sos"): the analog prototype's
    poles, prewarped and mapped by the bilinear transform; sections ordered with the
    poles nearest the unit circle last, the gain in the first."""
    if order % 2:
        raise ValueError("an even order (pairs of complex poles) is all the prefilter needs")
    wn = 2.0 * f_hz / fs  # fraction of the Nyquist frequency
    if not 0.0 < wn < 1.0:
        raise ValueError(f"cut-off {f_hz} Hz must lie between 0 and half the sample rate {fs} Hz")
    m = np.arange(-order + 1, order, 2)
    p_analog = -np.exp(1j * np.pi * m / (2 * order)) * (4.0 * np.tan(np.pi * wn / 2.0))
    p = (4.0 + p_analog) / (4.0 - p_analog)  # bilinear transform at fs = 2 (normalised)
    # the analog gain prod(-p) (unit gain at DC) times the bilinear transform's own
    gain = float(np.real(np.prod(-p_analog) / np.prod(4.0 - p_analog)))
    upper = p[p.imag > 0]
    upper = upper[np.argsort(np.abs(upper))]  # farthest from the unit circle first
    sos = np.zeros((len(upper), 6))
    sos[:, :3] = (1.0, 2.0, 1.0)  # every zero at z = -1
    sos[:, 3] = 1.0
    sos[:, 4] = -2.0 * upper.real
    sos[:, 5] = np.abs(upper) ** 2
    sos[0, :3] *= gain
    return sos


def _section(b, a, x: np.ndarray, x_past: np.ndarray) -> np.ndarray:
    """One biquad over the columns of x (n, m), started in the steady state of a
    constant input ``x_past`` (m,): the samples before the first equal x_past and the
    outputs before it the section's DC response to it (scipy's ``lfilter_zi``)."""
    n = len(x)
    dc = (b[0] + b[1] + b[2]) / (1.0 + a[1] + a[2])
    xp = np.concatenate([np.broadcast_to(x_past, (2, x.shape[1])), x])
    rhs = b[0] * xp[2:] + b[1] * xp[1:-1] + b[2] * xp[:-2]
    y_past = dc * x_past
    rhs[0] -= (a[1] + a[2]) * y_past
    if n > 1:
        rhs[1] -= a[2] * y_past
    band = np.zeros((3, n), order="F")  # LAPACK's layout: no copy on the way in
    band[0] = 1.0
    band[1, :-1] = a[1]
    band[2, :-2] = a[2]
    y, info = lapack.dtbtrs(band, rhs, uplo="L")
    if info != 0:  # a unit diagonal cannot be singular: only a malformed call lands here
        raise ValueError(f"LAPACK dtbtrs failed (info {info})")
    return y


def _cascade_steady(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Sections in turn over the columns of x, all started in the steady state of x[0]
    (scipy.signal.sosfilt with ``zi = sosfilt_zi(sos) * x[0]``)."""
    level = x[0].copy()
    y = x
    for s in sos:
        b, a = s[:3], s[3:]
        y = _section(b, a, y, level)
        level = level * (b[0] + b[1] + b[2]) / (1.0 + a[1] + a[2])
    return y


_compiled = None  # scipy.signal.sosfiltfilt, in a process that has asked for it (use_scipy_signal)


def use_scipy_signal() -> None:
    """Filter with scipy.signal's own sosfiltfilt from now on in this process: the same
    numbers to rounding (tests/test_filters.py), four times faster on a long run (its
    recursion is compiled; LAPACK's band solve takes 3 ms per section for 150,000
    samples). For a process that imports scipy.signal anyway: ``stid live`` re-filters the
    whole run at every update."""
    global _compiled
    from scipy import signal

    _compiled = signal.sosfiltfilt


def sosfiltfilt(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Zero-phase filtering as scipy.signal.sosfiltfilt (odd extension of
    3 * (2 * sections + 1) samples at each end, each pass started in steady state)."""
    x = np.asarray(x, float)
    one = x.ndim == 1
    X = x[:, None] if one else x
    edge = 3 * (2 * len(sos) + 1)
    if len(X) <= edge:
        raise ValueError(f"{len(X)} samples are too few to filter (need more than {edge})")
    if _compiled is not None:
        return _compiled(sos, x, axis=0, padtype="odd", padlen=edge)
    ext = np.concatenate([2 * X[:1] - X[edge:0:-1], X, 2 * X[-1:] - X[-2:-edge - 2:-1]])
    y = _cascade_steady(sos, ext)
    y = _cascade_steady(sos, y[::-1])[::-1]
    y = y[edge:-edge]
    return y[:, 0] if one else y


def fir_lowpass(numtaps: int, cutoff: float) -> np.ndarray:
    """Hamming-windowed sinc low-pass, unit DC gain (scipy.signal.firwin(numtaps,
    cutoff, window="hamming"); cutoff as a fraction of the Nyquist frequency)."""
    m = np.arange(numtaps) - 0.5 * (numtaps - 1)
    h = cutoff * np.sinc(cutoff * m) * np.hamming(numtaps)
    return h / h.sum()


def decimate(x: np.ndarray, q: int) -> np.ndarray:
    """Every q-th sample after a zero-phase FIR low-pass, as scipy.signal.decimate(x, q,
    ftype="fir", zero_phase=True): 20 q + 1 taps at 1/q of the Nyquist frequency,
    centred on the kept samples, zeros beyond the ends."""
    x = np.asarray(x, float)
    if q <= 1:
        return x
    half = 10 * q
    h = fir_lowpass(2 * half + 1, 1.0 / q)
    n_out = -(-len(x) // q)
    padded = np.concatenate([np.zeros(half), x, np.zeros(half + q)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)[: n_out * q: q]
    return windows @ h[::-1]
