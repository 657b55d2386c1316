"""Measured frequency responses: H1 estimates from Welch cross-spectra, with
coherence and the number of averages (which set each point's uncertainty)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from stid.fit.dataset import Stretch


@dataclass
class FRF:
    name: str
    vx: float
    f: np.ndarray  # Hz
    H: np.ndarray  # (2, n_f): ay/delta [m/s^2/rad], r/delta [1/s]
    coh: np.ndarray  # (2, n_f) magnitude-squared coherence
    n_avg: int  # Welch averages (independent segments, ~)
    fs: float

    def variance(self) -> np.ndarray:
        """Variance of each H1 point (Bendat & Piersol): (1 - g2) / (2 n_d g2) |H|^2."""
        g2 = np.clip(self.coh, 1e-3, 0.999)
        return (1 - g2) / (2 * self.n_avg * g2) * np.abs(self.H) ** 2


def segment_length(st: Stretch, lines: int = 25) -> float:
    """Welch segment [s]: ~``lines`` frequency lines inside the excited band (leakage bias
    shrinks with resolution), at least 5 s, at most a quarter of the record (variance)."""
    fs = 1.0 / st.dt
    x = st.steer - np.mean(st.steer)
    f, P = signal.welch(x, fs=fs, nperseg=int(min(len(x) // 2, 5 * fs)))
    edge = f[np.flatnonzero(P > 1e-2 * P.max())[-1]] if np.any(P > 0) else fs / 4
    T = len(x) / fs
    return float(np.clip(lines / max(edge, 1e-3), 5.0, max(T / 4, 1.0)))


def estimate_frf(st: Stretch, seg_s: float | None = None, f_min: float = 0.2, f_max: float | None = None) -> FRF:
    fs = 1.0 / st.dt
    n = len(st.steer)
    if seg_s is None:
        seg_s = segment_length(st)
    nperseg = int(min(n // 2, seg_s * fs))
    nperseg = max(nperseg, 16)
    x = st.steer - np.mean(st.steer)
    f, Pxx = signal.welch(x, fs=fs, nperseg=nperseg)
    H, coh = [], []
    for y in (st.ay, st.r):
        y = y - np.mean(y)
        _, Pxy = signal.csd(x, y, fs=fs, nperseg=nperseg)
        _, Pyy = signal.welch(y, fs=fs, nperseg=nperseg)
        H.append(Pxy / np.where(Pxx > 0, Pxx, np.inf))
        coh.append(np.abs(Pxy) ** 2 / np.maximum(Pxx * Pyy, 1e-300))
    H, coh = np.array(H), np.array(coh)
    # the band the steering excites: input power within 1% of its peak
    excited = Pxx > 1e-2 * Pxx[f >= f_min].max()
    hi = f_max if f_max is not None else fs / 4
    band = (f >= max(f_min, 2 * fs / nperseg)) & (f <= hi) & excited
    n_avg = max(1, int(2 * n / nperseg) - 1)  # 50% overlap
    out = FRF(st.name, st.vx, f[band], H[:, band], coh[:, band], n_avg, fs)
    out.sensors = st.sensors  # the chain the measured responses went through
    return out
