"""Sensor models from the datasheets: truth motion -> pin voltages.

ADXL335 (ratiometric): zero g at Vs/2, sensitivity Vs/10 per g (300 mV/g at 3 V),
noise 150 ug/sqrt(Hz) on x, y and 300 ug/sqrt(Hz) on z, bandwidth set by the
output capacitor with the internal 32 kOhm (0.1 uF -> 50 Hz), output clipped to
the rails. LISY300AL (absolute): 1.65 V at zero rate, 3.3 mV per deg/s, +-300
deg/s, internal low-pass ~88 Hz; noise density assumed 0.05 deg/s/sqrt(Hz)
(not found in a datasheet; stated here). The board's ADC (bits, reference,
clipping) is modelled by the simulated board, not here.

Accelerometers measure specific force in the body frame. With the body rolled by
phi (right side down positive, ISO 8855 x axis), the y axis tilts and sees
ay cos(phi) + g sin(phi).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from hil_sim.vehicle import G, CarParams, Effects, Trajectory, wheel_speeds


@dataclass
class SensorParams:
    vs: float = 3.3  # V, sensor supply = ADC reference
    acc_noise_xy: float = 150e-6  # g/sqrt(Hz)
    acc_noise_z: float = 300e-6
    acc_bandwidth: float = 50.0  # Hz (0.1 uF output capacitors)
    gyro_zero: float = 1.65  # V
    gyro_sens: float = 3.3e-3  # V per deg/s
    gyro_noise: float = 0.05  # deg/s/sqrt(Hz)
    gyro_bandwidth: float = 88.0  # Hz
    vib_engine_hz: float = 180.0  # Hz, engine/drivetrain vibration at speed
    vib_engine_amp: float = 3.0  # m/s^2 on the accelerometer before its filter
    vib_road_rms: float = 0.6  # m/s^2 broadband road roughness at 4 m/s
    vbat: float = 7.4  # V, two-cell LiPo
    vbat_divider: float = 0.25  # V at the pin per V of battery

    def acc_sens(self) -> float:
        return self.vs / 10.0  # V per g, ratiometric

    def as_dict(self):
        from dataclasses import asdict

        return asdict(self)


def body_signals(traj: Trajectory, car: CarParams, effects: Effects, t_start_bias: float, tg=None):
    """Specific force and yaw rate the sensors see, before sensor imperfections, on the
    integration grid or (tg) on a finer grid."""
    if tg is None:
        t = traj.t
        sig = {"ax": traj.ax, "ay": traj.ay, "r": traj.r, "r_dot": traj.r_dot, "phi": traj.phi}
        if "sensor_delay" in effects:  # the motion delay_s ago (held at the start)
            sig = {k: np.interp(t - car.sensor_delay_s, t, v) for k, v in sig.items()}
    else:
        t = tg
        # sensor_delay: the accelerometer and gyro outputs reach the ADC late (a sensor board's
        # digital filter or FIFO): what they show now is the motion of delay_s ago
        sig = traj.dense(tg - car.sensor_delay_s if "sensor_delay" in effects else tg)
    ax = sig["ax"].copy()
    ay = sig["ay"].copy()
    r = sig["r"].copy()
    az = np.full_like(ax, G)
    if "accel_offset" in effects:
        ay = ay + car.x_acc * sig["r_dot"]
        ax = ax - car.x_acc * r ** 2
    if "body_roll" in effects:
        ay0 = ay.copy()
        ay = ay * np.cos(sig["phi"]) + G * np.sin(sig["phi"])
        az = az * np.cos(sig["phi"]) - ay0 * np.sin(sig["phi"])
    if "sensor_bias" in effects:
        # thermal offset that drifts in after the still phase: a stand-still
        # calibration at the start of the run does not remove it
        ramp = np.clip((t - t_start_bias) / car.bias_ramp_s, 0, 1)
        r = r + car.bias_r * ramp
        ay = ay + car.bias_ay * ramp
    for e in effects.custom:  # a user's truth-side effect (hil_sim.effect_file)
        if e.sensor_signals is not None:
            out = e.sensor_signals(t, {"ax": ax, "ay": ay, "az": az, "r": r}, car)
            ax, ay, az, r = (np.asarray(out[k], float) for k in ("ax", "ay", "az", "r"))
    return ax, ay, az, r


def pin_voltages(traj: Trajectory, car: CarParams, effects: Effects, sens: SensorParams,
                 fs_sig: int, rng: np.random.Generator, t_start_bias: float):
    """Voltages of every analog output on a grid of ``fs_sig`` Hz, the whole run at once.

    Returns (t_grid, dict name -> volts) with names ax, ay, az, yaw, vbat.
    """
    n = grid_size(traj.t[-1], fs_sig)
    return PinVoltages(car, effects, sens, fs_sig, rng, t_start_bias, n).block(traj, 0, n)


def grid_size(t_end: float, fs_sig: int) -> int:
    """Points of the voltage grid for a run whose last truth instant is ``t_end`` [s]."""
    return int(t_end * fs_sig) + 1


class PinVoltages:
    """Voltages of every analog output on the grid k / fs_sig, k = 0 .. n - 1, computed
    block by block (``block``) in order; the blocks together are the whole-run result bit
    for bit. Each noise source is its own stretch of ``rng``'s stream, as the whole-run
    draw takes it (road x, y, z when vibrating, then ax, ay, az, gyro, n draws each): the
    generator's state at the start of each stretch is found once, up front, by drawing
    through the stream in pieces; the output filters carry their state across blocks."""

    _SKIP = 1 << 20  # draws per piece while skipping through a stretch

    def __init__(self, car: CarParams, effects: Effects, sens: SensorParams, fs_sig: int,
                 rng: np.random.Generator, t_start_bias: float, n: int):
        self.car, self.effects, self.sens, self.fs = car, effects, sens, fs_sig
        self.t_start_bias, self.n = t_start_bias, n
        names = (("road_x", "road_y", "road_z") if "vibration" in effects else ()) + ("ax", "ay", "az", "yaw")
        self.noise = {}
        for name in names:
            g = np.random.Generator(type(rng.bit_generator)())
            g.bit_generator.state = rng.bit_generator.state
            self.noise[name] = g
            for k in range(0, n, self._SKIP):
                rng.standard_normal(min(self._SKIP, n - k))
        # first-order output filters: (b, a), the first input value, the filter state
        self.filt = {}
        for name, fc in (("ax", sens.acc_bandwidth), ("ay", sens.acc_bandwidth), ("az", sens.acc_bandwidth),
                         ("yaw", sens.gyro_bandwidth)):
            b, a = signal.butter(1, fc, fs=fs_sig)
            self.filt[name] = [b, a, None, np.zeros(max(len(a), len(b)) - 1)]
        self.done = 0

    def _lowpass(self, name, x):
        # filtered about the run's first value, as a filter that has sat at it since ever
        f = self.filt[name]
        if f[2] is None:
            f[2] = x[0]
        y, f[3] = signal.lfilter(f[0], f[1], x - f[2], zi=f[3])
        return y + f[2]

    def block(self, traj: Trajectory, k0: int, k1: int):
        """(t_grid, dict name -> volts) for grid points k0 .. k1 - 1. ``traj`` must hold the
        truth over them (from the sensor delay before k0 / fs, or from the run's start)."""
        if k0 != self.done or not k0 < k1 <= self.n:
            raise ValueError(f"voltage blocks must follow each other: next is {self.done}, asked {k0}..{k1}")
        self.done = k1
        sens, fs_sig = self.sens, self.fs
        tg = np.arange(k0, k1) / fs_sig
        ax, ay, az, r = body_signals(traj, self.car, self.effects, self.t_start_bias, tg)
        vx = np.interp(tg, traj.t, traj.vx)
        n = len(tg)
        if "vibration" in self.effects:
            moving = np.clip(vx / 4.0, 0, 2)
            eng = sens.vib_engine_amp * moving * np.sin(2 * math.pi * sens.vib_engine_hz * tg * (0.7 + 0.3 * moving / 2))
            road = [sens.vib_road_rms * moving * self.noise[k].standard_normal(n) for k in ("road_x", "road_y", "road_z")]
            ax = ax + 0.5 * eng + road[0]
            ay = ay + eng + road[1]
            az = az + 2 * eng + road[2]
        white = math.sqrt(fs_sig / 2.0)
        s = sens.acc_sens()
        out = {}
        for name, a, nd in (("ax", ax, sens.acc_noise_xy), ("ay", ay, sens.acc_noise_xy), ("az", az, sens.acc_noise_z)):
            v = sens.vs / 2 + s * (a / G + nd * white * self.noise[name].standard_normal(n))
            out[name] = np.clip(self._lowpass(name, v), 0.0, sens.vs)
        rate_dps = np.degrees(r) + sens.gyro_noise * white * self.noise["yaw"].standard_normal(n)
        # gyro_scale: this part's sensitivity is not the datasheet's (the host converts with that)
        gain = sens.gyro_sens * (1.0 + self.car.gyro_sens_error if "gyro_scale" in self.effects else 1.0)
        v = sens.gyro_zero + gain * np.clip(rate_dps, -300, 300)
        out["yaw"] = self._lowpass("yaw", v)
        out["vbat"] = np.full(n, sens.vbat * sens.vbat_divider)
        return tg, out


def hall_edges_us(traj: Trajectory, car: CarParams, pulses_per_rev: int = 1) -> np.ndarray:
    """Times [us] at which the rear-wheel magnet passes the hall sensor."""
    return hall_edges_from_distance_us(traj.t, traj.s, car, pulses_per_rev)


def hall_edges_from_distance_us(t: np.ndarray, s: np.ndarray, car: CarParams, pulses_per_rev: int = 1) -> np.ndarray:
    """``hall_edges_us`` from the run's times [s] and distance travelled [m] alone."""
    circ = 2 * math.pi * car.wheel_radius / pulses_per_rev
    k = np.arange(1, int(s[-1] // circ) + 1) * circ
    return np.round(np.interp(k, s, t) * 1e6).astype(np.int64)


WHEEL_NAMES = ("fl", "fr", "rl", "rr")


def wheel_hall_edges_us(traj: Trajectory, car: CarParams, pulses_per_rev: int = 1) -> dict:
    """Hall edge times [us] of each wheel (fl, fr, rl, rr): a magnet passes the sensor
    every 1/pulses_per_rev revolution of that wheel's own rotation (the truth's wheel
    speeds, integrated to angle)."""
    return wheel_hall_edges_from_speeds_us(traj.t, wheel_speeds(traj, car), pulses_per_rev)


def wheel_hall_edges_from_speeds_us(t: np.ndarray, speeds, pulses_per_rev: int = 1) -> dict:
    """``wheel_hall_edges_us`` from the run's times [s] and the four wheels' speeds [rad/s]."""
    out = {}
    for name, w in zip(WHEEL_NAMES, speeds):
        angle = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
        step = 2 * math.pi / pulses_per_rev
        k = np.arange(1, int(angle[-1] // step) + 1) * step
        # angle never decreases (w >= 0); where it is flat interp takes the first crossing
        out[name] = np.round(np.interp(k, angle, t) * 1e6).astype(np.int64)
    return out
