"""Runs of a 1:10 car with two effects at once, written here from plain physics (not the
project's simulator, and not stid's models): the single track driven by a steering servo
with a first-order lag through a linkage, with a spool's yaw moment, on a track where the
speed swings +-25% around 3 and 7 m/s.

- servo: tau u' = c - u for the command c (the logged steer), exact for c held over a step;
- linkage: the road-wheel angle is delta = u (1 + k3 u^2) of the servo's output u;
- spool: both rear wheels turn at one speed, so their slip differs by t r / vx across the
  track t; with axle longitudinal stiffness Cx the forces make Mz = -(Cx t^2 / 4) r / vx;
- the body: lateral and yaw equations of the linear single track at the speed of the moment,
  integrated with the servo by RK4 at 1 kHz from a steer command band-limited at 3 Hz on a
  2 kHz grid, and read (with the command) at 100 Hz;
  ay = (Fyf + Fyr) / m is what an accelerometer at the CG reads.
White noise of 2% of each output's spread is added."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stid.run import Run
from stid.vehicle_file import Vehicle


@dataclass(frozen=True)
class Car10:
    mass: float = 3.7  # kg
    a: float = 0.16  # m
    b: float = 0.17  # m
    Iz: float = 0.05  # kg m^2
    Cf: float = 120.0  # N/rad per axle
    Cr: float = 140.0  # N/rad per axle
    track: float = 0.20  # m
    Cx: float = 400.0  # N per unit slip, rear axle
    tau: float = 0.040  # s, servo lag
    k3: float = 0.0  # 1/rad^2, linkage

    @property
    def L(self) -> float:
        return self.a + self.b

    @property
    def spool(self) -> float:
        """The spool's moment per unit r / vx [N m s]: Cx t^2 / 4."""
        return self.Cx * self.track ** 2 / 4

    def vehicle(self) -> Vehicle:
        """What a user would write in the vehicle file: mass and axle positions."""
        return Vehicle(name="1:10 car from physics", mass=self.mass, a=self.a, b=self.b)

    def truth(self, effects) -> dict:
        """The truth in stid's parameters: k_diff against L r / vx, k3 of the same cubic."""
        out = {"Cf": self.Cf, "Cr": self.Cr, "Iz": self.Iz}
        if "actuator_lag" in effects:
            out["tau_steer"] = self.tau
        if "locked_diff" in effects:
            out["k_diff"] = self.spool / self.L
        if "steering_nonlinearity" in effects:
            out["k3"] = self.k3
        return out


def _command(n, fs, seed, rms_deg, bw_hz):
    """Band-limited random steer on the integration grid (the logged steer samples it)."""
    rng = np.random.default_rng(seed)
    spec = np.fft.rfft(rng.standard_normal(n))
    spec[np.fft.rfftfreq(n, 1 / fs) > bw_hz] = 0.0
    c = np.fft.irfft(spec, n)
    return c * np.radians(rms_deg) / np.std(c)


SUB = 10  # RK4 steps per output sample (1 ms at 100 Hz); the command is on a grid twice as fine


def pair_run(car: Car10, effects, v0: float, seed: int, T: float = 30.0, fs: float = 100.0,
             rms_deg: float = 3.0, bw_hz: float = 3.0, noise: float = 0.02, swing: float = 0.25) -> Run:
    n = int(T * fs)
    h = 1.0 / (fs * SUB)
    cmd = _command(2 * n * SUB + 2, 2 * fs * SUB, seed, rms_deg, bw_hz)  # continuous: at every RK4 stage
    t = np.arange(n) / fs
    speed = lambda tt: v0 * (1 + swing * np.sin(2 * np.pi * tt / 7.0 + seed))  # noqa: E731
    tau = car.tau if "actuator_lag" in effects else 0.0
    k3 = car.k3 if "steering_nonlinearity" in effects else 0.0
    spool = car.spool if "locked_diff" in effects else 0.0
    m, a, b, Iz, Cf, Cr = car.mass, car.a, car.b, car.Iz, car.Cf, car.Cr

    def forces(x, v):
        vy, r, u = x
        delta = u * (1 + k3 * u * u)
        return Cf * (delta - (vy + a * r) / v), Cr * (-(vy - b * r) / v)

    def rhs(x, k):  # k: the stage's index on the command's grid
        tt = k / (2 * fs * SUB)
        v = speed(tt)
        ff, fr = forces(x, v)
        du = (cmd[k] - x[2]) / tau if tau > 0 else 0.0
        return np.array([(ff + fr) / m - v * x[1], (a * ff - b * fr - spool * x[1] / v) / Iz, du])

    # start in the steady state of the first steer (the servo settled on it)
    u0 = cmd[0]
    v = speed(0.0)
    A = np.array([[-(Cf + Cr) / (m * v), -(a * Cf - b * Cr) / (m * v) - v],
                  [-(a * Cf - b * Cr) / (Iz * v), -(a * a * Cf + b * b * Cr + spool) / (Iz * v)]])
    x = np.append(-np.linalg.solve(A, np.array([Cf / m, a * Cf / Iz]) * u0 * (1 + k3 * u0 * u0)), u0)
    ay, r = np.empty(n), np.empty(n)
    for i in range(n):
        if tau == 0:
            x[2] = cmd[2 * i * SUB]
        ff, fr = forces(x, speed(t[i]))
        ay[i], r[i] = (ff + fr) / m, x[1]
        for j in range(SUB):
            k = 2 * (i * SUB + j)
            if tau == 0:  # the wheel follows the command itself
                x[2] = cmd[k]
            k1 = rhs(x, k)
            k2 = rhs(x + 0.5 * h * k1, k + 1)
            k3_ = rhs(x + 0.5 * h * k2, k + 1)
            k4 = rhs(x + h * k3_, k + 2)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3_ + k4)
    rng = np.random.default_rng(1000 + seed)
    ay = ay + noise * np.std(ay) * rng.standard_normal(n)
    r = r + noise * np.std(r) * rng.standard_normal(n)
    return Run(name=f"track {v0:g} m/s", t=t, steer=cmd[:2 * n * SUB:2 * SUB], ay=ay, r=r, vx=speed(t))


def pair_runs(car: Car10, effects, seed: int, speeds=(3.0, 7.0), rms_deg=3.0, **kw) -> list:
    """A run at each speed; ``rms_deg``: the steer's rms, or one per speed (a driver steers less
    at speed: the same lateral acceleration takes a steer ~1/v^2)."""
    rms = rms_deg if isinstance(rms_deg, (tuple, list)) else [rms_deg] * len(speeds)
    return [pair_run(car, effects, v, seed=10 * seed + k, rms_deg=a, **kw) for k, (v, a) in enumerate(zip(speeds, rms))]
