"""The per-sample SI view of a run (``/stid/samples``): what a person plots.

One JSON object per sample, in SI units by the sensors' datasheet conversions
(``host.units``) and the HELLO. It is for looking at a run (Foxglove's Plot panel
plots one scalar per message against log time); the identifier never reads it:
it takes the exact counts from ``/stid/frames`` and calibrates them itself.
"""

from __future__ import annotations

import math

import numpy as np

from host import units
from host.protocol import MOD

# a typical RC servo, for viewing only: 1500 us centre, +-500 us for +-25 degrees
VIEW_STEER_CENTER_S = 1500e-6
VIEW_STEER_S_PER_RAD = 500e-6 / math.radians(25.0)


class SiView:
    """Turns sample records of one boot into JSON lines; keeps the wheel state between calls."""

    def __init__(self, hello: dict):
        self.hello = hello
        wheels = units.declared_wheels(hello)
        self.ppr = int(wheels[0].get("pulses_per_rev", 1)) if wheels else 1
        self.mod = int(hello.get("mod") or MOD)
        self._count: int | None = None  # wheel count of the last sample seen
        self._edge_us: int | None = None  # MCU time of the last hall edge
        self._rate = float("nan")
        self.latest = (float("nan"), float("nan"))

    def columns(self, arr, t_mcu_us) -> dict:
        """SI columns for the samples ``arr`` (p.DECODED_DTYPE) taken at ``t_mcu_us`` (unwrapped)."""
        h = self.hello
        ax = units.accel_si(arr["ax"], h)
        ay = units.accel_si(arr["ay"], h)
        az = units.accel_si(arr["az"], h)
        r = units.yaw_rate_si(arr["yaw"], h)
        pulse = arr["steer_us"].astype(float) * 1e-6
        pulse[arr["steer_us"] == 0] = np.nan
        steer = (pulse - VIEW_STEER_CENTER_S) / VIEW_STEER_S_PER_RAD
        return {"ax": ax, "ay": ay, "az": az, "r": r, "steer_pulse": pulse, "steer": steer,
                "wheel_rate": self._wheel_rate(arr, np.asarray(t_mcu_us, dtype=np.int64))}

    def _wheel_rate(self, arr, t_mcu) -> np.ndarray:
        """Angular speed over the last two hall edges [rad/s], held until the next edge."""
        cnt = arr["wheel_count"].astype(np.int64)
        edge = t_mcu - (arr["t_us"].astype(np.int64) - arr["wheel_t_us"].astype(np.int64)) % self.mod
        prev = cnt[0] if self._count is None else self._count
        dc = np.diff(np.concatenate([[prev], cnt])) % 65536
        new = np.flatnonzero(dc > 0)
        out = np.full(len(cnt), np.nan)
        rate = self._rate
        last_edge = self._edge_us
        if len(new):
            e = edge[new]
            pe = np.concatenate([[last_edge if last_edge is not None else -1], e[:-1]])
            dt = (e - pe) * 1e-6
            ok = (pe >= 0) & (dt > 0)
            rates = np.where(ok, dc[new] * (2 * math.pi / self.ppr) / np.where(ok, dt, 1.0), np.nan)
            # forward fill: each sample holds the rate of the latest edge at or before it
            seg = np.searchsorted(new, np.arange(len(cnt)), side="right") - 1
            out = np.where(seg >= 0, rates[np.maximum(seg, 0)], rate)
            rate = float(rates[-1])
            last_edge = int(e[-1])
        else:
            out[:] = rate
        self._count = int(cnt[-1])
        self._edge_us = last_edge
        self._rate = rate
        return out

    def lines(self, boot: str, arr, index, t_mcu_us, t0_us: int) -> list[bytes]:
        """One JSON document per sample (no integer beyond 2^53: the index is < 2^30)."""
        c = self.columns(arr, t_mcu_us)
        t = (np.asarray(t_mcu_us, dtype=np.int64) - t0_us) * 1e-6
        cols = [t] + [c[k] for k in _ORDER]
        head = '{"boot":%s,"index":' % _json_str(boot)
        fmt = head + '%d,"t":%.6f,' + ",".join(f'"{k}":%.6g' for k in _ORDER) + "}"
        rows = zip(np.asarray(index).tolist(), *(np.asarray(v, dtype=float).tolist() for v in cols))
        out = [(fmt % row) for row in rows]
        if len(c["ay"]):
            self.latest = (float(c["ay"][-1]), float(c["r"][-1]))
        # JSON has no NaN: a value the board did not measure is null
        return [(line.replace("nan", "null") if "nan" in line else line).encode() for line in out]


_ORDER = ("ax", "ay", "az", "r", "steer_pulse", "steer", "wheel_rate")


def _json_str(text: str) -> str:
    import json

    return json.dumps(str(text))
