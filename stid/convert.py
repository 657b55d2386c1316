"""Counts -> SI: datasheet defaults from the HELLO content, refined by the
vehicle file's [sensors] (written by ``stid calibrate``), and the per-run gyro
bias from still stretches."""

from __future__ import annotations

import math

import numpy as np

from host import units
from stid import segments
from stid.vehicle_file import Vehicle

G = units.G


def mount_rotation(roll: float, pitch: float) -> np.ndarray:
    """Rotation from sensor axes to body axes: undo a mounting roll then pitch."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    return (Ry @ Rx).T


def accelerations(samples, hello: dict, vehicle: Vehicle):
    """Body-frame specific force (ax, ay, az) [m/s^2]; az is NaN when not sampled."""
    acc = np.vstack([units.accel_si(samples[k], hello) for k in ("ax", "ay", "az")])
    off = np.asarray(vehicle.sensors.get("accel_offset", [0.0, 0.0, 0.0]), dtype=float).reshape(3, 1)
    acc = acc - off
    roll = float(vehicle.sensors.get("mount_roll", 0.0))
    pitch = float(vehicle.sensors.get("mount_pitch", 0.0))
    if roll or pitch:
        az = np.where(np.isnan(acc[2]), np.sqrt(np.maximum(G ** 2 - acc[0] ** 2 - acc[1] ** 2, 0)), acc[2])
        acc = mount_rotation(roll, pitch) @ np.vstack([acc[0], acc[1], az])
    return acc[0], acc[1], acc[2]


def yaw_rate(samples, hello: dict, vehicle: Vehicle):
    v = units.counts_to_volts(samples["yaw"], hello)
    zero = float(vehicle.sensors.get("gyro_zero_v", units.GYRO_ZERO_V))
    sens = float(vehicle.sensors.get("gyro_v_per_dps", units.GYRO_V_PER_DPS))
    return np.radians((v - zero) / sens)


def steer_angle(steer_us, vehicle: Vehicle):
    us = np.asarray(steer_us, dtype=float)
    return np.where(us > 0, (us - vehicle.steer_center_us) / vehicle.steer_us_per_rad, np.nan)


def gyro_bias_from_still(r: np.ndarray, vx: np.ndarray, fs: float):
    """Mean yaw rate while standing still, or None when the run never stands still."""
    mask = segments.still_mask(vx, fs)
    if mask.sum() < 0.5 * fs:
        return None
    return float(np.mean(r[mask]))
