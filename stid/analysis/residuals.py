"""Residual analysis in the manner of MATLAB's ``resid``: autocorrelation of the
residuals (are they white?) and their cross-correlation with the input (is
anything in the steer left unexplained?), each with a 99% band."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from stid.stats import tau_int_blocks, xcorr as _xcorr

Z99 = 2.576


@dataclass
class ResidualAnalysis:
    lags_s: np.ndarray
    auto: dict  # output -> autocorrelation at lags >= 0
    cross: dict  # output -> cross-correlation with steer, lags -max..max (positive: residual after steer)
    band: float  # 99% band for white residuals: 2.576 / sqrt(N)
    tau_int: dict  # output -> integrated autocorrelation time [samples]
    n: int
    cross_band: dict = None  # output -> 99% band of the cross-correlation (Bartlett, coloured series)

    def white(self, output: str) -> bool:
        k = len(self.lags_s) // 2
        return bool(np.mean(np.abs(self.auto[output][1:k]) > self.band) < 0.05)

    def independent(self, output: str) -> bool:
        band = self.cross_band[output] if self.cross_band else self.band
        return bool(np.mean(np.abs(self.cross[output]) > band) < 0.05)

    def peak_lag_s(self, output: str) -> float:
        c = self.cross[output]
        return float(self.lags_s[np.argmax(np.abs(c))])


def analyse(predictions, max_lag_s: float = 0.5) -> ResidualAnalysis:
    """Residual statistics over every stretch of a fit (stretches are concatenated per
    statistic by averaging the correlations, weighted by length)."""
    dt = float(predictions[0].t[1] - predictions[0].t[0])
    L = max(2, int(max_lag_s / dt))
    outs = ("ay", "r")
    auto = {o: np.zeros(L + 1) for o in outs}
    cross = {o: np.zeros(2 * L + 1) for o in outs}
    bart = {o: 0.0 for o in outs}
    n_tot = 0
    for p in predictions:
        k = p.keep
        e = (p.y - p.yhat)[k]
        u = p.steer[k]
        n = len(u)
        if n <= 2 * L:
            continue
        for i, o in enumerate(outs):
            auto[o] += n * _xcorr(e[:, i], e[:, i], L)[L:]
            cross[o] += n * _xcorr(e[:, i], u, L)
            # Bartlett: var r_eu(k) ~ (1/N) sum_j rho_ee(j) rho_uu(j) for independent coloured series
            ree = _xcorr(e[:, i], e[:, i], L)
            ruu = _xcorr(u, u, L)
            bart[o] += n * float(np.sum(ree * ruu))
        n_tot += n
    n_tot = max(n_tot, 1)
    taus = dict(zip(outs, tau_int_blocks([(p.y - p.yhat)[p.keep] for p in predictions], L)))
    return ResidualAnalysis(lags_s=np.arange(-L, L + 1) * dt, auto={o: v / n_tot for o, v in auto.items()},
                            cross={o: v / n_tot for o, v in cross.items()}, band=Z99 / np.sqrt(n_tot),
                            tau_int={o: float(v) for o, v in taus.items()}, n=n_tot,
                            cross_band={o: Z99 * np.sqrt(max(v / n_tot, 1.0) / n_tot) for o, v in bart.items()})


def noise_autocorrelation(fs_raw: float, dt: float, sensor_hz: float = 0.0, max_lag_s: float = 0.5,
                          n: int = 1 << 16) -> np.ndarray:
    """What a correct model's residual autocorrelation is when the sensor's noise is white:
    the autocorrelation, at lags 0..max_lag_s of the fit's sample time ``dt``, of white noise
    sampled at ``fs_raw``, through the sensor's first-order output filter (``sensor_hz``; 0:
    none) and the fit's prefilter and decimation (stid.fit.dataset.filtered). These colour any
    residual: judged against zero with the white-noise band, even a correct model fails. (A
    fixed seed: the same curve each time; its own sampling error is about 1/sqrt(n/q), below
    the band drawn around it.)"""
    from stid.fit.dataset import _decimate, prefilter

    q = max(1, int(round(dt * fs_raw)))
    x = np.random.default_rng(0).standard_normal(n)
    if sensor_hz and sensor_hz < 0.45 * fs_raw:
        a = np.exp(-2 * np.pi * sensor_hz / fs_raw)  # the first-order filter, sampled
        from scipy.signal import lfilter

        x = lfilter([1 - a], [1, -a], x)
    e = _decimate(prefilter(x, fs_raw), q)
    L = max(2, int(max_lag_s / dt))
    return _xcorr(e, e, L)[L:]


def coloured_band(rho: np.ndarray, n: int) -> float:
    """99% band of a sample autocorrelation around ``rho`` (Bartlett: a series with that
    autocorrelation, ``n`` samples; at lags past its correlation time)."""
    return float(Z99 * np.sqrt((1 + 2 * np.sum(rho[1:] ** 2)) / max(n, 1)))
