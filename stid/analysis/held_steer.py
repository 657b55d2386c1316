"""What the car does while the steer is held: the kinematic steering gain, with no model.

Held long enough for the response to settle, a car drives a circle of curvature
kappa = r / vx, and its road wheels point L kappa plus the difference of the axles' slip
angles (delta = L kappa + alpha_f - alpha_r). At low speed and gentle cornering the slip
angles are small against L kappa, so

    L r / (vx steer)  ~  1

whatever the tyres, when ``steer`` is the road-wheel angle. A logged steer that is a
command the wheels follow only in part (servo travel, linkage, a wrong [steering] gain)
shows here as a ratio far from 1. A regression of L r / vx on the steer over the whole run
does not measure this: the response lags the steer (servo, command latency), and a lagged
response regressed on its input comes out smaller than it is (the FrictionMaps car's 0.6 at
1-2 m/s was that: held, it turns 0.93-1.10 of its command).

How far from 1 tyres can move the ratio is bounded by how soft or stiff tyres are: with
normalised cornering stiffness c = C / Fz per axle, alpha_f - alpha_r = K ay with
K = (1/c_f - 1/c_r) / g, so at speed v the ratio lies within L / (L +- K_max v^2)
(``tyre_band``), K_max from the plausible range (stid.fit.plausibility).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

G = 9.81
# A servo answers in 0.05-0.16 s (HARDWARE.md) and a scale car's yaw settles in a few tenths:
# the first SETTLE_S of a hold is the response getting there, the rest is averaged.
SETTLE_S = 0.5
MIN_AVERAGED_S = 0.3
HOLD_TOL_RAD = 0.005  # 0.3 deg: a command that moves less is held (a joystick's jitter)
MIN_STEER_RAD = 0.03  # below ~2 deg a trim of a degree would be half the ratio
MOVING_MPS = 1.0
# Gentle: a tyre's force is within ~20% of linear below ~half its friction limit (brush
# model), and at friction 0.6 that is 0.3 g; the slip-angle allowance takes the 25% more.
GENTLE_AY = 0.3 * G
NONLINEAR_ALLOWANCE = 1.25


@dataclass
class Hold:
    """One stretch of held steer, its settled part averaged."""

    run: str
    t0: float  # s, start of the averaged part
    seconds: float
    steer: float  # rad, as logged
    speed: float  # m/s
    turned: float  # L r / vx [rad]: the road-wheel angle a slip-free car needs for this curvature
    ay: float  # m/s^2
    vx_r: float  # m/s^2


def holds(run, wheelbase: float, valid_only: bool = True) -> list[Hold]:
    """The run's stretches of held steer, moving above MOVING_MPS and cornering gently, each
    averaged after SETTLE_S."""
    steer = np.asarray(run.steer, float)
    vx = np.asarray(run.vx, float)
    fs = run.fs
    ok = np.isfinite(steer) & np.isfinite(vx) & np.isfinite(run.r) & np.isfinite(run.ay)
    if valid_only and run.valid is not None:
        ok &= np.asarray(run.valid, bool)
    out = []
    settle, need = int(round(SETTLE_S * fs)), max(int(round(MIN_AVERAGED_S * fs)), 2)
    i, n = 0, len(steer)
    while i < n:
        j = i + 1
        while j < n and abs(steer[j] - steer[i]) <= HOLD_TOL_RAD and ok[j]:
            j += 1
        a = i + settle
        if j - a >= need and ok[i] and abs(steer[i]) >= MIN_STEER_RAD:
            sl = slice(a, j)
            good = (vx[sl] > MOVING_MPS) & (np.abs(run.ay[sl]) <= GENTLE_AY)
            if good.sum() >= need:
                v, r, ay = vx[sl][good], np.asarray(run.r, float)[sl][good], np.asarray(run.ay, float)[sl][good]
                out.append(Hold(run.name, float(run.t[a]), good.sum() / fs, float(np.mean(steer[sl])),
                                float(np.mean(v)), float(np.mean(wheelbase * r / v)), float(np.mean(ay)),
                                float(np.mean(v * r))))
        i = j
    return out


@dataclass
class SteeringGain:
    """L r / (vx steer) over the holds: how much of the logged steer the car turned by."""

    gain: float
    se: float  # standard error from the holds' scatter (nan with fewer than three)
    seconds: float
    n: int
    speeds: tuple  # (slowest, fastest) hold speed [m/s]
    band: tuple  # what tyres within the plausible range give at these speeds
    speed_ratio: float  # ay / (vx r) on the holds: ~1 when vx and the sensors read true

    def far_from_one(self) -> bool:
        lo, hi = self.band
        se = self.se if np.isfinite(self.se) else 0.0
        return self.gain + 2 * se < lo or self.gain - 2 * se > hi

    def words(self) -> str:
        v0, v1 = self.speeds
        speeds = f"{v0:.1f} m/s" if round(v0, 1) == round(v1, 1) else f"{v0:.1f}-{v1:.1f} m/s"
        holds = f"{self.n} hold{'s' if self.n != 1 else ''}"
        return (f"L r / (vx steer) = {self.gain:.2f} over {self.seconds:.1f} s of held steer ({holds}, {speeds}), "
                f"where tyres give {self.band[0]:.2f}-{self.band[1]:.2f}")


def tyre_band(speed_sq: float, wheelbase: float, c_range) -> tuple:
    """The range of L r / (vx delta) tyres with normalised stiffness in ``c_range`` (per axle,
    /rad) give in steady gentle cornering at mean squared speed ``speed_sq``."""
    lo, hi = c_range
    k_max = NONLINEAR_ALLOWANCE * (1.0 / lo - 1.0 / hi) / G  # rad per m/s^2
    d = k_max * speed_sq / wheelbase
    return 1.0 / (1.0 + d), (1.0 / (1.0 - d) if d < 1.0 else float("inf"))


# Faster, tyres alone move the ratio so far that a calibration error hides in it: holds count
# where the plausible tyres' band stays within 1/(1 + 0.5) .. 1/(1 - 0.5), i.e. 0.67-2.
MAX_TYRE_SHARE = 0.5
MIN_HELD_S = 1.0  # in all: less is a glimpse, not a measurement


def slow_holds(runs, wheelbase: float, c_range) -> list[Hold]:
    """The runs' holds slow enough that tyres in ``c_range`` move the ratio by at most
    MAX_TYRE_SHARE."""
    lo, hi = c_range
    k_max = NONLINEAR_ALLOWANCE * (1.0 / lo - 1.0 / hi) / G
    v_max = np.sqrt(MAX_TYRE_SHARE * wheelbase / k_max)
    return [h for r in runs for h in holds(r, wheelbase) if h.speed <= v_max]


def steering_gain(runs, wheelbase: float, c_range) -> SteeringGain | None:
    """The kinematic steering gain from the runs' slow holds (``slow_holds``), or None when
    they hold their steer that slowly for less than MIN_HELD_S."""
    return gain_of(slow_holds(runs, wheelbase, c_range), wheelbase, c_range)


def gain_of(hs: list[Hold], wheelbase: float, c_range) -> SteeringGain | None:
    """L r / (vx steer) over the holds ``hs``, or None when they last less than MIN_HELD_S.

    The gain is the least-squares slope through the origin of the turned angle on the steer,
    each hold weighted by its seconds (a trim shifts a left and a right hold alike and leaves
    the slope)."""
    if sum(h.seconds for h in hs) < MIN_HELD_S:
        return None
    w = np.array([h.seconds for h in hs])
    s = np.array([h.steer for h in hs])
    k = np.array([h.turned for h in hs])
    gain = float(np.sum(w * s * k) / np.sum(w * s * s))
    if len(hs) >= 3:
        per = k / s
        se = float(np.sqrt(np.sum(w * (per - gain) ** 2) / np.sum(w) / (len(hs) - 1)))
    else:
        se = float("nan")
    v = np.array([h.speed for h in hs])
    band = tyre_band(float(np.sum(w * v ** 2) / np.sum(w)), wheelbase, c_range)
    vxr = np.array([h.vx_r for h in hs])
    ay = np.array([h.ay for h in hs])
    speed_ratio = float(np.sum(w * vxr * ay) / np.sum(w * vxr * vxr)) if np.any(vxr) else float("nan")
    return SteeringGain(gain, se, float(w.sum()), len(hs), (float(v.min()), float(v.max())), band, speed_ratio)

