"""Manoeuvres a vehicle engineer drives, as steering command and speed target.

Every manoeuvre starts standing still (so the gyro bias can be taken from the
start of the run), accelerates to speed, then steers. Steering commands are in
road-wheel radians, positive to the left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

MANOEUVRES = ("random_steer", "chirp", "steady_circle", "step_steer", "double_lane_change", "standstill")
SPEED_PROFILES = ("constant", "track")


@dataclass
class Manoeuvre:
    name: str
    t: np.ndarray
    delta_cmd: np.ndarray  # rad, before the servo's 50 Hz pulse train
    v_ref: np.ndarray  # m/s
    path: tuple | None = None  # (x, y) of the path a driver follows, for double lane change


@dataclass
class Plan:
    """What to drive. Units SI; angles of the road wheel in rad."""

    name: str = "random_steer"
    duration: float = 30.0  # s of manoeuvre after the run-up
    speed: float = 4.0  # m/s
    steer_amp: float = 0.05  # rad: rms for random steer, amplitude otherwise
    bandwidth: float = 4.0  # Hz, random steer / chirp upper frequency
    still: float = 2.0  # s standing still at the start
    run_up: float = 3.0  # s to accelerate before steering
    speed_end: float | None = None  # steady_circle: speed at the end of the sweep
    speed_profile: str = "constant"  # "track": accelerate and brake every few seconds
    speed_swing: float = 0.25  # track: the speed target moves within +-this fraction of `speed`


def _ramp(t, t0, t1):
    return np.clip((t - t0) / (t1 - t0), 0.0, 1.0)


def build(plan: Plan, dt: float, rng: np.random.Generator) -> Manoeuvre:
    if plan.name not in MANOEUVRES:
        raise ValueError(f"unknown manoeuvre {plan.name!r}; choose one of {', '.join(MANOEUVRES)}")
    total = plan.still + (0 if plan.name == "standstill" else plan.run_up) + plan.duration
    t = np.arange(int(round(total / dt))) * dt
    t_go = plan.still
    t_steer = plan.still + plan.run_up
    v_ref = plan.speed * _ramp(t, t_go, t_go + 0.6 * plan.run_up)
    # whole-run arrays are made only where used: a 10-minute run's are 5 MB each, and
    # random_steer's filter needs several more at once (stid-sim --fast's memory peak)
    delta = None
    tm = t - t_steer if plan.name in ("chirp", "steady_circle", "step_steer") else None
    on = t >= t_steer
    path = None
    if plan.name == "standstill":
        v_ref[:] = 0.0
    elif plan.name == "random_steer":
        # band-limited white noise: flat up to the bandwidth, then a steep roll-off
        fs = 1.0 / dt
        sos = signal.butter(6, plan.bandwidth, fs=fs, output="sos")
        w = signal.sosfiltfilt(sos, rng.standard_normal(len(t)))
        w *= plan.steer_amp / np.std(w[on])
        w *= _ramp(t, t_steer, t_steer + 0.5)  # fade in
        delta = w
    elif plan.name == "chirp":
        f0 = 0.2
        delta = np.where(on, plan.steer_amp * signal.chirp(tm, f0, plan.duration, plan.bandwidth,
                                                           method="logarithmic", phi=-90), 0.0)
    elif plan.name == "steady_circle":
        # constant steer, speed swept slowly so every point is (quasi) steady state
        v_end = plan.speed_end if plan.speed_end is not None else 2.5 * plan.speed
        v_ref = np.where(on, plan.speed + (v_end - plan.speed) * np.clip(tm / plan.duration, 0, 1), v_ref)
        delta = plan.steer_amp * _ramp(t, t_steer, t_steer + 1.0)
    elif plan.name == "step_steer":
        period = 4.0
        k = np.floor(tm / period)
        delta = np.where(on & (np.mod(tm, period) < period / 2), plan.steer_amp * np.where(k % 2 == 0, 1, -1), 0.0)
    elif plan.name == "double_lane_change":
        path = _lane_change_path(plan)
    if delta is None:
        delta = np.zeros_like(t)
    if plan.speed_profile not in SPEED_PROFILES:
        raise ValueError(f"unknown speed profile {plan.speed_profile!r}; choose one of {', '.join(SPEED_PROFILES)}")
    if plan.speed_profile == "track" and plan.name not in ("standstill", "steady_circle"):
        v_ref = np.where(on, _track_speed(t, t_steer, plan, rng), v_ref)
    return Manoeuvre(plan.name, t, delta, v_ref, path)


def _track_speed(t, t_steer, plan: Plan, rng: np.random.Generator) -> np.ndarray:
    """A driver on a track: a new speed target every 2-5 s, alternately above and below the
    plan's speed by 50-100% of speed_swing (accelerate out of a corner, brake into the
    next), reached by throttle or brake; the first target is the run-up speed."""
    if not 0 <= plan.speed_swing < 1:
        raise ValueError("speed swing must be a fraction in [0, 1)")
    times, targets = [t_steer], [plan.speed]
    while times[-1] < t[-1]:
        times.append(times[-1] + rng.uniform(2.0, 5.0))
        side = 1 if len(targets) % 2 else -1
        targets.append(plan.speed * (1 + side * plan.speed_swing * rng.uniform(0.5, 1.0)))
    # hold each target, with a smooth (raised-cosine) change over the first 1.5 s of its hold
    # each hold's stretch on its own: whole-run temporaries per target cost time and memory
    v = np.full(len(t), plan.speed)
    edges = np.searchsorted(t, times, side="left")  # first instant at or after each change
    for k in range(1, len(times)):
        stop = edges[k + 1] if k + 1 < len(times) else len(t)
        tk = t[edges[k]:stop]
        ramp = 0.5 * (1 - np.cos(np.pi * np.clip((tk - times[k]) / 1.5, 0, 1)))
        v[edges[k]:stop] = targets[k - 1] + (targets[k] - targets[k - 1]) * ramp
    return v


def _lane_change_path(plan: Plan):
    """ISO 3888-1-like double lane change scaled to the car: cone gates 1.5 m apart
    (lateral offset of the second lane), entry 4 m, shift 5 m, side lane 3 m,
    shift back 5 m, exit 6 m; then straight to the end of the run."""
    offset = 1.5
    x_sections = np.cumsum([0, 4.0, 5.0, 3.0, 5.0, 6.0])
    x = np.linspace(0, 200, 20001)
    y = np.zeros_like(x)
    s1 = (x >= x_sections[1]) & (x < x_sections[2])
    y[s1] = offset * 0.5 * (1 - np.cos(np.pi * (x[s1] - x_sections[1]) / 5.0))
    y[(x >= x_sections[2]) & (x < x_sections[3])] = offset
    s3 = (x >= x_sections[3]) & (x < x_sections[4])
    y[s3] = offset * 0.5 * (1 + np.cos(np.pi * (x[s3] - x_sections[3]) / 5.0))
    return x, y


def pure_pursuit(path, x, y, psi, vx, wheelbase, lookahead_time=0.35, min_lookahead=0.6):
    """Steering command of a driver following ``path``: pure pursuit on a look-ahead point."""
    px, py = path
    ld = max(min_lookahead, lookahead_time * vx)
    i = np.searchsorted(px, x + ld)
    i = min(i, len(px) - 1)
    dx, dy = px[i] - x, py[i] - y
    alpha = math.atan2(dy, dx) - psi
    return math.atan2(2.0 * wheelbase * math.sin(alpha), ld)
