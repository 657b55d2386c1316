"""Where the error lives: fit percent per frequency band, per |ay| bin (linear range
vs the friction limit) and per run and speed, for each model."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from stid.fit.result import fit_percent

BANDS_HZ = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0))
OUTS = ("ay", "r")


@dataclass
class Breakdown:
    by_band: dict = field(default_factory=dict)  # "1-2 Hz" -> {"ay": %, "r": %}
    by_ay: dict = field(default_factory=dict)  # "|ay| 2-4 m/s^2" -> {...}
    by_run: dict = field(default_factory=dict)  # "run (4.0 m/s)" -> {...}


def band_fit(y: np.ndarray, yhat: np.ndarray, fs: float, lo: float, hi: float) -> float:
    """Fit percent of the part of y between lo and hi Hz (energy of residual vs signal there)."""
    nper = min(len(y), int(4 * fs))
    f, Pe = signal.welch(y - yhat, fs=fs, nperseg=nper)
    _, Py = signal.welch(y - y.mean(), fs=fs, nperseg=nper)
    m = (f >= lo) & (f < hi)
    if not m.any() or Py[m].sum() <= 0:
        return float("nan")
    return float(100 * (1 - np.sqrt(Pe[m].sum() / Py[m].sum())))


def breakdown(predictions, ay_edges=(0.0, 2.0, 4.0, 6.0, np.inf)) -> Breakdown:
    out = Breakdown()
    y = np.vstack([p.y[p.keep] for p in predictions])
    yh = np.vstack([p.yhat[p.keep] for p in predictions])
    fs = 1.0 / float(predictions[0].t[1] - predictions[0].t[0])
    for lo, hi in BANDS_HZ:
        vals = {}
        for i, o in enumerate(OUTS):
            parts = [band_fit(p.y[p.keep, i], p.yhat[p.keep, i], fs, lo, hi) for p in predictions]
            w = [int(p.keep.sum()) for p in predictions]
            ok = [(v, n) for v, n in zip(parts, w) if np.isfinite(v)]
            vals[o] = float(np.average([v for v, _ in ok], weights=[n for _, n in ok])) if ok else float("nan")
        out.by_band[f"{lo:g}-{hi:g} Hz"] = vals
    a = np.abs(y[:, 0])
    for lo, hi in zip(ay_edges[:-1], ay_edges[1:]):
        m = (a >= lo) & (a < hi)
        if m.sum() < 50:
            continue
        # fit of the samples in the bin, against the variation of the whole output
        out.by_ay[f"|ay| {lo:g}-{hi:g} m/s^2" if np.isfinite(hi) else f"|ay| > {lo:g} m/s^2"] = {
            o: float(100 * (1 - np.sqrt(np.mean((y[m, i] - yh[m, i]) ** 2) / np.var(y[:, i]))))
            for i, o in enumerate(OUTS)}
    for p in predictions:
        out.by_run[f"{p.name} ({p.vx:.1f} m/s)"] = {o: fit_percent(p.y[p.keep, i], p.yhat[p.keep, i])
                                                    for i, o in enumerate(OUTS)}
    return out
