"""``stid calibrate``: sensor zeros and mounting from a stand-still recording,
steering calibration from steady circles; written into the vehicle file.

Stand-still on level ground: the accelerometer must read (0, 0, +g) in body
axes and the gyro zero. With az measured, the direction of gravity gives the
mounting roll and pitch; a single level stand-still cannot tell a tilted sensor
from a zero-g offset on x and y, so without az the x/y readings are taken as
offsets (for a few degrees the two differ by under 0.2% in dynamics).

Steering: on a circle at low speed the front wheel angle is delta = atan(L/R)
with R = vx/r (kinematic, no slip). Steady stretches at two or more servo pulse
widths give the centre pulse and the pulse change per radian.
"""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np
import tomlkit

from host import units
from host.errors import HostError
from host.mcap_read import read_log
from stid import segments
from stid.convert import mounting_from_gravity
from stid.errors import InputError
from stid.output_paths import refuse_existing
from stid.vehicle_file import Vehicle, load_vehicle

G = units.G


def standstill(path, vehicle: Vehicle) -> dict:
    try:
        log = read_log(path)
    except HostError as e:
        raise InputError(str(e)) from None
    s = log.samples
    if not log.hello:
        raise InputError(f"{path} holds no HELLO frame, so the ADC scale is unknown: log the stand-still "
                         "for a few seconds longer (the firmware repeats HELLO every 2 s)")
    if len(s) < 200:
        raise InputError(f"{path}: {len(s)} samples are too few for a stand-still calibration (need ≥ 200)")
    hello = log.hello
    acc = {k: units.accel_si(s[k], hello) for k in ("ax", "ay", "az")}
    moving = np.diff(s["wheel_count"].astype(np.int64)) != 0
    if moving.any():
        raise InputError(f"{path}: the wheels turned during the recording; calibrate standing still")
    r_v = units.counts_to_volts(s["yaw"], hello)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a channel the board does not sample is all NaN
        noise = {k: float(np.nanstd(v)) if np.isfinite(v).any() else float("nan") for k, v in acc.items()}
    if max(v for v in noise.values() if np.isfinite(v)) > 0.5:
        raise InputError(f"{path}: the accelerometer is not still (std up to "
                         f"{max(noise.values()):.2f} m/s^2); calibrate with the engine off, car at rest")
    mean = {k: float(np.nanmean(v)) if np.isfinite(v).any() else None for k, v in acc.items()}
    out = {"gyro_zero_v": float(np.mean(r_v))}
    notes = []
    if mean["az"] is not None:
        gx, gy, gz = mean["ax"], mean["ay"], mean["az"]
        norm = math.sqrt(gx * gx + gy * gy + gz * gz)
        if abs(norm - G) > 0.1 * G:
            raise InputError(f"{path}: the accelerometer reads {norm:.2f} m/s^2 at rest instead of "
                             f"{G} m/s^2: wrong supply voltage or sensor part in HELLO?")
        roll, pitch = mounting_from_gravity(np.array([gx, gy, gz]))
        out["mount_roll"], out["mount_pitch"] = roll, pitch
        out["accel_offset"] = [0.0, 0.0, float(norm - G)]
        notes.append(f"mounting roll {math.degrees(out['mount_roll']):+.2f} deg, pitch "
                     f"{math.degrees(out['mount_pitch']):+.2f} deg from the direction of gravity")
    else:
        out["accel_offset"] = [float(mean["ax"]), float(mean["ay"]), 0.0]
        out["mount_roll"] = 0.0
        out["mount_pitch"] = 0.0
        notes.append("az is not sampled on this board: x/y readings at rest taken as offsets "
                     "(a tilt and an offset look the same on level ground)")
    out["_notes"] = notes
    out["_gyro_bias_rad_s"] = float(np.radians((out["gyro_zero_v"] - units.GYRO_ZERO_V) / units.GYRO_V_PER_DPS))
    return out


def standstill_ros(path, vehicle: Vehicle) -> dict:
    """The IMU's mounting roll and pitch from a ROS bag's stand-still (its own direction of
    gravity; the bag's gyro zero is taken from each run's stand-still when it is loaded)."""
    import dataclasses

    from stid.load import load_file

    # measured as the IMU sits, whatever the vehicle file declares now
    bare = dataclasses.replace(vehicle, sensors={k: v for k, v in vehicle.sensors.items()
                                                 if k not in ("mount_roll", "mount_pitch")})
    tilts = [r.meta["imu_tilt"] for r in load_file(path, bare) if r.meta.get("imu_tilt")]
    if not tilts:
        raise InputError(f"{path}: no stand-still of 0.5 s with gravity in the accelerometer (a driver that removes "
                         "gravity hides the tilt): record the car standing still for a few seconds")
    out = dict(tilts[0])
    out["_notes"] = [f"mounting roll {math.degrees(out['mount_roll']):+.2f} deg, pitch "
                     f"{math.degrees(out['mount_pitch']):+.2f} deg from the direction of gravity (ROS IMU)"]
    return out


def is_ros(path, vehicle: Vehicle) -> bool:
    from stid.ros import bag, topic_files

    return bool(bag.kind_of(path)) or (Path(path).is_dir() and topic_files.names_files(vehicle.ros))


def steering_from_circles(paths, vehicle: Vehicle) -> dict:
    from stid.load import load_file

    pulses, angles = [], []
    for p in paths:
        for run in load_file(p, vehicle):
            fs = run.fs
            mask = segments.steady_state(run.steer, run.ay, run.r, run.vx, fs)
            mask &= (run.vx > 0.5) & (np.abs(run.ay) < 0.15 * G)  # low speed: kinematic steering
            if mask.sum() < fs:
                continue
            # the pulse widths behind run.steer, from the current calibration
            us = run.steer * vehicle.steer_us_per_rad + vehicle.steer_center_us
            for a, b in segments.runs_of(mask, int(fs)):
                pulses.append(float(np.mean(us[a:b])))
                angles.append(float(np.arctan(vehicle.L * np.mean(run.r[a:b]) / np.mean(run.vx[a:b]))))
    if len(pulses) < 2 or np.ptp(pulses) < 50:
        raise InputError("steering calibration needs steady circles at two or more steering settings "
                         "(e.g. one left and one right) driven slowly (ay below 0.15 g)")
    slope, center_angle = np.polyfit(pulses, angles, 1)
    us_per_rad = 1.0 / slope
    center = -center_angle / slope
    return {"center_us": float(center), "us_per_rad": float(us_per_rad), "_points": len(pulses)}


def _replace_table(text: str, name: str, values: dict) -> str:
    """Replace (or append) one [table] of a TOML text, keeping everything else (comments,
    layout, the other tables)."""
    doc = tomlkit.parse(text)
    if name not in doc:
        doc[name] = tomlkit.table()
    for k, v in values.items():  # in place: the user's comments in the table stay too
        if not k.startswith("_"):
            doc[name][k] = [float(x) for x in v] if isinstance(v, (list, tuple, np.ndarray)) else v
    return tomlkit.dumps(doc)


def calibrate_cli(standstill_path: str, vehicle_path: str, circles=(), output: str | None = None,
                  overwrite: bool = False) -> int:
    """Without ``output`` the vehicle file is updated in place (its previous text kept as
    FILE.bak); ``output``: write there instead, never over an existing file unless ``overwrite``."""
    out = Path(output or vehicle_path)
    if out.is_dir() or not out.absolute().parent.is_dir():  # said first, not after the results
        raise InputError(f"-o {out}: " + ("is a directory; give a file path" if out.is_dir() else
                                         f"the directory {out.absolute().parent} does not exist; create it or "
                                         "give another path"))
    if output is not None and Path(output).resolve() != Path(vehicle_path).resolve():
        refuse_existing([out], "stid calibrate -o", overwrite)
    vehicle = load_vehicle(vehicle_path)
    if Path(standstill_path).suffix.lower() == ".csv" and not is_ros(standstill_path, vehicle):
        # (a trial user's valid CSV was called "not an MCAP file ... corrupted")
        raise InputError(f"{standstill_path}: stid calibrate takes a stand-still logged by stid-log (MCAP: the raw "
                         "sensor voltages and the board's HELLO) or a ROS bag; a CSV in SI units carries neither. A "
                         "CSV run's gyro zero is taken from its own stand-still when it is fitted")
    st = standstill_ros(standstill_path, vehicle) if is_ros(standstill_path, vehicle) else \
        standstill(standstill_path, vehicle)
    sensors = dict(vehicle.sensors)
    sensors.update({k: v for k, v in st.items() if not k.startswith("_")})
    text = Path(vehicle_path).read_text()
    text = _replace_table(text, "sensors", sensors)
    if "gyro_zero_v" in st:
        print(f"gyro zero {st['gyro_zero_v']:.4f} V (bias {st['_gyro_bias_rad_s']:+.4f} rad/s against the "
              f"datasheet 1.65 V); accelerometer offsets {np.round(st['accel_offset'], 3).tolist()} m/s^2",
              file=sys.stderr)
    for n in st["_notes"]:
        print(n, file=sys.stderr)
    if circles:
        sc = steering_from_circles(circles, vehicle)
        steering = dict(vehicle.raw.get("steering", {}))
        steering.update({"center_us": sc["center_us"], "us_per_rad": sc["us_per_rad"]})
        text = _replace_table(text, "steering", steering)
        print(f"steering: centre {sc['center_us']:.1f} us, {sc['us_per_rad']:.1f} us per rad "
              f"(from {sc['_points']} steady stretches)", file=sys.stderr)
    if out.exists() and output is None:
        out.with_suffix(out.suffix + ".bak").write_text(Path(vehicle_path).read_text())
    out.write_text(text)
    print(f"wrote {out}" + (f" (previous version kept as {out}.bak)" if output is None else ""), file=sys.stderr)
    return 0
