"""Find the parts of a run that serve each fit: standing still, constant speed,
steady-state cornering; trim start-up transients."""

from __future__ import annotations

import numpy as np


def uniform_filter1d(x: np.ndarray, size: int) -> np.ndarray:
    """Centred moving average with edge values repeated (as scipy.ndimage's 'nearest')."""
    x = np.asarray(x, float)
    size = max(1, int(size))
    pad_l, pad_r = size // 2, size - 1 - size // 2
    xp = np.concatenate([np.full(pad_l, x[0]), x, np.full(pad_r, x[-1])])
    c = np.concatenate([[0.0], np.cumsum(xp)])
    return (c[size:] - c[:-size]) / size


def runs_of(mask: np.ndarray, min_len: int):
    """(start, stop) index pairs of True stretches at least ``min_len`` long."""
    m = np.concatenate([[False], mask.astype(bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    pairs = edges.reshape(-1, 2)
    return [(int(a), int(b)) for a, b in pairs if b - a >= min_len]


# A speed that reads noise about zero at rest (an odometry, a fused estimate) is judged by its
# mean over STILL_MEAN_S, each sample within STILL_NOISE x v_still: a trial user's odometry read
# +-0.07 m/s at rest (sd 0.02), and sample by sample its 3 s stand-still fell into pieces under
# 0.5 s ("stands still for under 0.5 s, too little to show the gyro's zero"). A wheel sensor's,
# which reads exactly 0 at rest, is judged sample by sample, as it always was.
STILL_MEAN_S = 0.2
STILL_NOISE = 4.0
EXACT_ZERO_S = 0.25  # this long at exactly 0: a speed that reads 0 at rest


def still_mask(vx: np.ndarray, fs: float, v_still: float = 0.05, min_s: float = 0.5) -> np.ndarray:
    """True where the car stands still (no wheel motion) for at least ``min_s``."""
    vx = np.asarray(vx, float)
    mask = np.abs(vx) < v_still
    if len(vx) and not runs_of(vx == 0.0, max(1, int(EXACT_ZERO_S * fs))):
        mean = uniform_filter1d(np.nan_to_num(vx), max(1, int(round(STILL_MEAN_S * fs))))
        mask = (np.abs(mean) < v_still) & (np.abs(vx) < STILL_NOISE * v_still)
    out = np.zeros(len(vx), bool)
    # the edges of a still stretch still move (rolling to a stop): keep its core
    trim = int(0.1 * fs)
    for a, b in runs_of(mask, int(min_s * fs)):
        out[a + trim:max(a + trim, b - trim)] = True
    return out


def constant_speed(vx: np.ndarray, fs: float, tol: float = 0.05, min_s: float = 3.0, v_min: float = 0.5):
    """(start, stop) stretches where the speed stays within +-tol (relative) of the
    stretch's own middle speed: a linear model at one speed fits them. A slow speed
    sweep is not constant speed, however smooth it is locally."""
    win = max(3, int(fs))
    mean = uniform_filter1d(vx, win)
    moving = (vx > v_min) & (mean > v_min)
    out = []
    n_min = int(min_s * fs)
    for a, b in runs_of(moving, n_min):
        i = a
        while i < b:
            lo = hi = mean[i]
            j = i
            while j < b:
                lo2, hi2 = min(lo, mean[j]), max(hi, mean[j])
                if hi2 - lo2 > 2 * tol * 0.5 * (hi2 + lo2):
                    break
                lo, hi = lo2, hi2
                j += 1
            if j - i >= n_min:
                out.append((int(i), int(j)))
            i = j if j > i else i + 1
    return out


def steady_state(steer, ay, r, vx, fs: float, window_s: float = 0.5, rate_tol: float = 0.15):
    """Boolean mask of quasi-steady cornering: yaw rate and speed change slowly
    compared with their size (|dr/dt| window_s < rate_tol |r|)."""
    win = max(3, int(window_s * fs))
    r_s = uniform_filter1d(r, win)
    dr = np.gradient(r_s) * fs
    v_s = uniform_filter1d(vx, win)
    dv = np.gradient(v_s) * fs
    st = uniform_filter1d(steer, win)
    dst = np.gradient(st) * fs
    ok = (np.abs(dr) * window_s < rate_tol * np.maximum(np.abs(r_s), 0.05))
    ok &= np.abs(dv) * window_s < 0.1 * np.maximum(v_s, 0.5)
    ok &= np.abs(dst) * window_s < rate_tol * np.maximum(np.abs(st), 0.005)
    ok &= v_s > 0.5
    return ok


def moving_start(vx: np.ndarray, fs: float, v_frac: float = 0.8, settle_s: float = 1.0) -> int:
    """Index after which the car has reached most of its running speed and settled
    (start-up transient trimmed)."""
    if len(vx) == 0:
        return 0
    v_run = np.percentile(vx, 75)
    if v_run <= 0.3:
        return 0
    above = np.flatnonzero(vx > v_frac * v_run)
    return int(min(len(vx), (above[0] if len(above) else 0) + settle_s * fs))
