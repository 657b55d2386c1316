"""MCU time on the host: unwrap the 2^30 wrap of ticks_us, and map MCU time to
host time with a fitted offset and drift.

The MCU clock is the one to trust for sample spacing (a crystal, sampled in an
interrupt); the host clock gives absolute time. Host receive times are late by a
variable USB/OS delay that is never negative, so the clock model is fitted to the
lower envelope of (host - mcu): the minimum per one-second bin, then a straight
line through those minima.
"""

from __future__ import annotations

import numpy as np

from host.protocol import MOD


class TickUnwrapper:
    """Turn ticks modulo 2^30 into a monotonic microsecond count.

    Across a long silence (a disconnect longer than the 17.9 min wrap) the number
    of wraps is taken from the host clock, which is why ``update`` takes the host
    time too.
    """

    def __init__(self):
        self.last_raw: int | None = None
        self.last_host_us: float | None = None
        self.value = 0

    def update(self, raw: int, host_us: float) -> int:
        if self.last_raw is None:
            self.value = raw
        else:
            step = (raw - self.last_raw) % MOD
            if step > MOD // 2:  # a sample slightly older than the last one (frame t vs sample t)
                step -= MOD
            if self.last_host_us is not None and host_us - self.last_host_us > MOD / 2:
                # silent for longer than half a wrap: count wraps from the host clock
                elapsed = host_us - self.last_host_us
                wraps = round((elapsed - step) / MOD)
                step += wraps * MOD
            self.value += step
        self.last_raw = raw
        self.last_host_us = host_us
        return self.value

    def unwrap_array(self, raw: np.ndarray, host_us: float) -> np.ndarray:
        """Unwrap an array of consecutive ticks (one frame's samples)."""
        raw = np.asarray(raw, dtype=np.int64)
        base = self.update(int(raw[0]), host_us)
        steps = np.diff(raw) % MOD
        steps[steps > MOD // 2] -= MOD
        out = base + np.concatenate([[0], np.cumsum(steps)])
        self.value = int(out[-1])
        self.last_raw = int(raw[-1])
        return out


class ClockModel:
    """host_time ≈ offset + (1 + drift) · mcu_time, fitted on the lower envelope."""

    def __init__(self, bin_s: float = 1.0):
        self.bin_us = bin_s * 1e6
        self._bins: dict[int, tuple[float, float]] = {}  # bin -> (mcu_us, host-mcu min)

    def add(self, mcu_us: float, host_us: float) -> None:
        k = int(mcu_us // self.bin_us)
        d = host_us - mcu_us
        cur = self._bins.get(k)
        if cur is None or d < cur[1]:
            self._bins[k] = (mcu_us, d)

    def fit(self) -> dict:
        if not self._bins:
            return {"offset_us": 0.0, "drift_ppm": 0.0, "points": 0, "residual_us": None}
        pts = np.array(sorted(self._bins.values()))
        if len(pts) < 3:
            return {"offset_us": float(pts[0, 1]), "drift_ppm": 0.0, "points": len(pts), "residual_us": None}
        A = np.column_stack([np.ones(len(pts)), pts[:, 0]])
        coef, *_ = np.linalg.lstsq(A, pts[:, 1], rcond=None)
        resid = pts[:, 1] - A @ coef
        return {"offset_us": float(coef[0]), "drift_ppm": float(coef[1] * 1e6), "points": len(pts),
                "residual_us": float(np.std(resid))}

    def to_host_us(self, mcu_us, fit: dict | None = None):
        f = fit or self.fit()
        return np.asarray(mcu_us) * (1 + f["drift_ppm"] * 1e-6) + f["offset_us"]
