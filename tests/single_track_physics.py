"""A linear single track written here from plain physics, apart from stid's models and the
simulator: a small car driven slowly by a teleoperator's steer (levels held for a while,
moved between in a tenth of a second), integrated by RK4 at 500 Hz (its fastest pole, at
1 m/s, is ~65 /s) with the speed varying, and sampled like a real log (noise on ay, r, vx).
What the tests change is what the log says: the steer column a factor off the road wheels,
a clip, a wheel speed that spins up.

Equations (ISO 8855, small angles): slip angles alpha_f = delta - (vy + a r) / vx,
alpha_r = -(vy - b r) / vx; m (vy' + vx r) = Cf alpha_f + Cr alpha_r; Iz r' = a Cf alpha_f -
b Cr alpha_r; ay = vy' + vx r.
"""

from __future__ import annotations

import numpy as np

G = 9.81


class Car:
    """A 1:10 car (F1TENTH class, HARDWARE.md): 3.5 kg, L = 0.33 m, Iz 0.05 kg m^2, and a
    normalised cornering stiffness of 6 /rad front, 7 /rad rear (a slight understeer)."""

    def __init__(self, mass=3.5, a=0.15, b=0.18, Iz=0.05, c_front=6.0, c_rear=7.0):
        self.mass, self.a, self.b, self.Iz = mass, a, b, Iz
        self.L = a + b
        self.Cf = c_front * mass * G * b / self.L
        self.Cr = c_rear * mass * G * a / self.L

    def toml(self) -> str:
        return f"name = \"plain-physics 1:10\"\nmass = {self.mass}\na = {self.a}\nb = {self.b}\n"


def held_steer(duration, fs, rng, amplitude=0.25, hold=(0.8, 2.5), move_s=0.12, levels=None):
    """A teleoperator's road-wheel angle [rad]: random levels within +-amplitude (or drawn from
    ``levels``), each held 0.8-2.5 s, moved between along a ramp of ``move_s``."""
    t = np.arange(int(duration * fs)) / fs
    out = np.zeros_like(t)
    now, value = 0.0, 0.0
    while now < duration:
        new = (rng.choice(levels) if levels is not None else rng.uniform(-amplitude, amplitude))
        span = rng.uniform(*hold)
        seg = (t >= now) & (t < now + span)
        ramp = np.clip((t[seg] - now) / move_s, 0.0, 1.0)
        out[seg] = value + (new - value) * ramp
        now, value = now + span, new
    return out


def drive(car: Car, steer, fs, speed, dt=2e-3):
    """Integrate the single track with road-wheel angle ``steer`` (sampled at ``fs``, taken
    linearly between samples) at speed ``speed`` (an array at ``fs`` or a number).
    Returns (ay, r, vy) at the samples."""
    n = len(steer)
    v = np.broadcast_to(np.asarray(speed, float), (n,))
    m, a, b, Iz, Cf, Cr = car.mass, car.a, car.b, car.Iz, car.Cf, car.Cr

    def deriv(x, d, vx):
        vy, r = x
        af = d - (vy + a * r) / vx
        ar = -(vy - b * r) / vx
        fy, mz = Cf * af + Cr * ar, a * Cf * af - b * Cr * ar
        return np.array([fy / m - vx * r, mz / Iz]), fy / m

    sub = max(int(round(1.0 / (fs * dt))), 1)
    h = 1.0 / (fs * sub)
    x = np.zeros(2)
    ay, r, vy = np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(n):
        _, ay[i] = deriv(x, steer[i], v[i])
        r[i], vy[i] = x[1], x[0]
        if i == n - 1:
            break
        for j in range(sub):
            f0, f1 = j / sub, (j + 1) / sub
            d0 = steer[i] + (steer[i + 1] - steer[i]) * f0
            d1 = steer[i] + (steer[i + 1] - steer[i]) * f1
            dm = 0.5 * (d0 + d1)
            v0 = v[i] + (v[i + 1] - v[i]) * f0
            v1 = v[i] + (v[i + 1] - v[i]) * f1
            vm = 0.5 * (v0 + v1)
            k1, _ = deriv(x, d0, v0)
            k2, _ = deriv(x + 0.5 * h * k1, dm, vm)
            k3, _ = deriv(x + 0.5 * h * k2, dm, vm)
            k4, _ = deriv(x + h * k3, d1, v1)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ay, r, vy


def log_csv(path, t, steer, ay, r, vx, rng, noise=(0.15, 0.004, 0.02), extra=None):
    """Write a CSV in stid's import contract with white noise of rms ``noise`` on ay, r, vx."""
    import pandas as pd

    cols = {"t": t, "steer": steer, "ay": ay + noise[0] * rng.standard_normal(len(t)),
            "r": r + noise[1] * rng.standard_normal(len(t)),
            "vx": np.where(vx > 0, vx + noise[2] * rng.standard_normal(len(t)), 0.0)}
    cols.update(extra or {})
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.7g")
    return path
