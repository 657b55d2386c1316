"""The excitation map: how much steering the data hold at each speed and frequency.

The bicycle's response changes with speed and with frequency; a parameter is learnt
from the places where the steer excites what depends on it. The map is the steer's
power spectral density in windows of WINDOW_S seconds, each added at its mean speed:
seconds x deg^2/Hz per cell, so a driver sees where the data are thin.
"""

from __future__ import annotations

import numpy as np

WINDOW_S = 2.0
SPEED_STEP = 0.5  # m/s per row
F_MAX = 10.0  # Hz: above this a driver's steering holds little (and the fits stop at 16-20 Hz)
F_STEP = 0.5  # Hz per column (the window's resolution)


def speed_frequency_map(runs) -> dict | None:
    """{"speeds": row lower edges [m/s], "freqs": column centres [Hz], "power": rows of
    seconds x deg^2/Hz, "seconds": driving seconds per row}; None without driving."""
    from stid.fit.dataset import V_MOVING

    rows: dict = {}
    secs: dict = {}
    freqs = None
    for r in runs:
        fs = r.fs
        n = int(WINDOW_S * fs)
        if len(r.t) < n:
            continue
        k = len(r.t) // n
        steer = np.degrees(r.steer[:k * n]).reshape(k, n)
        vx = r.vx[:k * n].reshape(k, n).mean(axis=1)
        moving = vx > V_MOVING
        if not moving.any():
            continue
        x = steer[moving] - steer[moving].mean(axis=1, keepdims=True)
        w = np.hanning(n)
        # one-sided PSD per window [deg^2/Hz], Hann-windowed periodogram
        P = 2.0 * np.abs(np.fft.rfft(x * w, axis=1)) ** 2 / (fs * np.sum(w ** 2))
        f = np.fft.rfftfreq(n, 1 / fs)
        edges = np.arange(0.0, F_MAX + F_STEP / 2, F_STEP)
        col = np.digitize(f, edges) - 1
        inside = (col >= 0) & (col < len(edges) - 1) & (f > 0)
        binned = np.zeros((len(x), len(edges) - 1))
        for j in range(len(edges) - 1):
            sel = inside & (col == j)
            if sel.any():
                binned[:, j] = P[:, sel].mean(axis=1)
        freqs = 0.5 * (edges[:-1] + edges[1:])
        for v, row in zip(vx[moving], binned):
            key = int(v // SPEED_STEP)
            rows[key] = rows.get(key, 0.0) + row * WINDOW_S
            secs[key] = secs.get(key, 0.0) + WINDOW_S
    if not rows:
        return None
    keys = range(min(rows), max(rows) + 1)
    return {"speeds": [round(k * SPEED_STEP, 2) for k in keys], "freqs": [round(float(x), 3) for x in freqs],
            "power": [[round(float(p), 5) for p in rows.get(k, np.zeros(len(freqs)))] for k in keys],
            "seconds": [round(secs.get(k, 0.0), 1) for k in keys], "unit": "s deg^2/Hz"}
