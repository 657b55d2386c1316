"""Intervals that stay true when the model is not exactly the car.

The time-domain fit's standard errors (a Newey-West sandwich on the residuals) are
right about noise. They say nothing about model error: a model that is slightly
wrong gives estimates that move with the conditions of each piece of data (speed,
amplitude, which manoeuvre), and a noise-only interval then rarely contains the
truth. A delete-a-block jackknife sees that movement: the data are cut into K
contiguous blocks (whole seconds of driving, so the residuals' correlation stays
inside a block), the model is refitted K times with one block left out, and the
spread of those estimates is the parameter's variance under noise *and* the model
error that varies between blocks. Each refit is one Gauss-Newton step from the
full estimate with the block's rows removed from the Jacobian and residuals (the
linearised jackknife): leaving out an eighth of the data moves the estimate
little, so the step is the refit to first order, at no simulation cost. An error that is the same in every block (a
bias common to all the data) is invisible to any interval computed from the data;
the README's accuracy table measures that part on the simulator.

The interval printed is the wider of the two, per parameter, with Student's t on
K - 1 degrees of freedom when the jackknife is the wider one.
"""

from __future__ import annotations

import numpy as np

BLOCK_MIN_S = 4.0  # a block must outlast the residuals' correlation (~0.5 s) many times over
K_MAX = 8
K_MIN = 5  # fewer blocks give a variance too uncertain to be worth printing


def blocks(keeps: list, dts: list, k_max: int = K_MAX) -> list:
    """K masks per stretch (lists of bool arrays), each selecting one contiguous block of
    the kept samples; empty when the data are too short for K_MIN blocks."""
    counts = [int(k.sum()) for k in keeps]
    seconds = sum(c * dt for c, dt in zip(counts, dts))
    K = int(min(k_max, seconds // BLOCK_MIN_S))
    if K < K_MIN:
        return []
    total = sum(counts)
    edges = np.linspace(0, total, K + 1).round().astype(int)
    out = []
    for b in range(K):
        lo, hi = edges[b], edges[b + 1]
        masks, start = [], 0
        for k, c in zip(keeps, counts):
            idx = np.flatnonzero(k)
            m = np.zeros(len(k), bool)
            sel = idx[max(lo - start, 0):max(min(hi - start, c), 0)]
            m[sel] = True
            masks.append(m)
            start += c
        out.append(masks)
    return out


def jackknife_cov(J: np.ndarray, r: np.ndarray, row_block: np.ndarray, K: int) -> np.ndarray | None:
    """Delete-a-block jackknife covariance in the fit's own coordinates, linearised: J and
    r are the Jacobian and residuals at the optimum, ``row_block`` each row's block (0..K-1)."""
    if K < K_MIN:
        return None
    xs = []
    for b in range(K):
        keep = row_block != b
        Jb, rb = J[keep], r[keep]
        step, *_ = np.linalg.lstsq(Jb, -rb, rcond=None)
        xs.append(step)
    xs = np.array(xs)
    d = xs - xs.mean(axis=0)
    return (K - 1) / K * (d.T @ d)


def combine(cov_noise: np.ndarray, cov_jack: np.ndarray | None):
    """Per parameter the wider of the two variances, keeping the noise covariance's
    correlations: (covariance, which parameters the jackknife widened)."""
    if cov_jack is None:
        return cov_noise, []
    vn = np.maximum(np.diag(cov_noise), 1e-300)
    vj = np.diag(cov_jack)
    scale = np.sqrt(np.maximum(vj / vn, 1.0))
    return cov_noise * np.outer(scale, scale), [i for i, s in enumerate(scale) if s > 1.0]


# -- an error common to all the data, that grows with the steering amplitude -----------
#
# The jackknife's blocks are alike (each holds a few seconds of the same driving), so an
# error common to all of them is invisible to it. The commonest such error in a linear
# single track is a nonlinearity: large-angle geometry (the front force acts along the
# wheel, cos(delta)), tyre curvature, the speed the steering drags off. Left and right
# are symmetric, so it grows with the square of the amplitude, and the cornering
# stiffness a user wants is the slope at zero slip: the linear limit. So the data are
# split at the median of the steer's local amplitude, the estimate refitted on each
# half (one Gauss-Newton step, as the jackknife), and when the halves disagree by more
# than their noise (|z| > Z_SIGNIFICANT), the interval is widened by the extrapolated
# distance from the estimate to its zero-amplitude limit, assuming an amplitude^2 law.
# (The halves share the vehicle's memory across their boundaries, so this sees only
# part of the dependence: it is a lower bound on that error, not its measure.)

AMPLITUDE_WINDOW_S = 1.0
Z_SIGNIFICANT = 2.0


def amplitude_envelope(steer: np.ndarray, dt: float, window_s: float = AMPLITUDE_WINDOW_S) -> np.ndarray:
    """Local rms of the steer about its local mean [rad], over a centred window."""
    from stid.segments import uniform_filter1d

    w = max(3, int(window_s / dt))
    m = uniform_filter1d(steer, w)
    return np.sqrt(np.maximum(uniform_filter1d((steer - m) ** 2, w), 0.0))


def _step(J, r, rows):
    step, *_ = np.linalg.lstsq(J[rows], -r[rows], rcond=None)
    return step


def amplitude_allowance(J: np.ndarray, r: np.ndarray, amp_rows: np.ndarray, sandwich):
    """How far the estimate sits from its zero-amplitude limit, in the fit's coordinates,
    where the data show it; zeros where the halves agree within noise.

    ``amp_rows`` is the steer amplitude at each residual row; ``sandwich(mask)`` returns
    the noise covariance of a refit on the rows in ``mask``. Returns (allowance, z)."""
    lo = amp_rows <= np.median(amp_rows)
    hi = ~lo
    p = J.shape[1]
    if lo.sum() < 4 * p or hi.sum() < 4 * p:
        return np.zeros(p), np.zeros(p)
    x_lo, x_hi = _step(J, r, lo), _step(J, r, hi)
    var = np.diag(sandwich(lo)) + np.diag(sandwich(hi))
    z = (x_hi - x_lo) / np.sqrt(np.maximum(var, 1e-300))
    a2 = amp_rows ** 2
    e_all, e_lo, e_hi = a2.mean(), a2[lo].mean(), a2[hi].mean()
    if e_hi - e_lo <= 1e-12 * max(e_all, 1e-300):
        return np.zeros(p), z
    bias = (x_hi - x_lo) * e_all / (e_hi - e_lo)  # the estimate minus its zero-amplitude limit
    return np.where(np.abs(z) > Z_SIGNIFICANT, np.abs(bias), 0.0), z
