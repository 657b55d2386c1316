"""Convert one FrictionMaps F1/10 dataset (AhmadAmine998/FrictionMaps, MIT) into stid's CSV
contract (DESIGN.md: t, steer, ay, r, vx, ax; SI units, ISO 8855 axes).

The dataset was written by the authors' ``stateLogger.py`` ROS 2 node: one CSV per topic,
each row stamped with its message's header (columns ``s``, ``ns``). What the files hold,
read from that node and from the VESC driver (f1tenth/vesc, ``vesc_packet.cpp``) rather
than from the dataset README, which gets the IMU units wrong:

- ``imuData.csv`` (``/sensors/imu``, ``vesc_msgs/VescImuStamped``): accelerations in g
  WITH gravity (az ~ 1 at rest), angular rates in deg/s, Euler angles in deg. The VESC is
  mounted turned 90 deg about z: its x axis points to the LEFT of the car and its y axis to
  the rear, so ay = +imu.ax * g0, ax = -imu.ay * g0, r = +imu.wz (checked against the
  particle filter's heading: correlation 0.96-0.99, slope 1.01-1.07 over DS1, DS3-DS5).
- ``commandData.csv`` (``/ackermann_cmd``): ``delta`` is the Ackermann steering command in
  rad, left positive (REP 103), clipped at +-0.34 rad. It is the COMMAND to the servo, not
  a measured wheel angle; the VESC holds the last value until the next, so each sample is
  that staircase's mean over the sample period centred on it (stid.held_command: the value
  at the instant would move every step by up to half a sample, here 17 ms).
- ``odomData.csv`` (``/odom``, VESC odometry): ``vx`` from the motor's electrical RPM and a
  speed-to-ERPM gain: wheel speed, with the drive's slip in it. Its logged yaw-rate
  columns are copies of the linear velocity (a bug in the logger) and are not used.
- ``pfPoseData.csv`` (``/pf/viz/inferred_pose``, the particle filter on the lidar): the
  heading, kept as the extra column ``psi_pf`` [rad, unwrapped, ISO z-up] so that a test
  can check a yaw-rate bias against a measurement the identifier never sees.

All channels are put on one uniform grid at the IMU's median period (linear interpolation
of the sensors, the held command's mean over each sample period), over the span every topic covers.

Usage: python tools/real_logs/convert_frictionmaps.py DataSets/DS1 OUT.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from stid.held_command import interval_means

G0 = 9.80665  # m/s^2 per g: the VESC reports accelerations in g
DEG = np.pi / 180.0


def read_topic(folder: Path, name: str) -> pd.DataFrame:
    path = folder / f"{name}.csv"
    if not path.is_file():
        raise SystemExit(f"error: {path} not found; give a FrictionMaps dataset folder (DataSets/DSn)")
    df = pd.read_csv(path, index_col=0)
    df["t"] = df["s"] + df["ns"] * 1e-9  # the ROS header stamp, not the arrival time
    if np.any(np.diff(df["t"].to_numpy()) <= 0):
        raise SystemExit(f"error: {path}: header stamps are not increasing; this converter does not reorder")
    return df


def heading_from_quaternion(qx, qy, qz, qw) -> np.ndarray:
    """Yaw angle [rad] of a planar pose, unwrapped (the pose quaternion is a rotation about z)."""
    psi = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return np.unwrap(psi)


def convert(folder: Path) -> pd.DataFrame:
    imu = read_topic(folder, "imuData")
    cmd = read_topic(folder, "commandData")
    odom = read_topic(folder, "odomData")
    pose = read_topic(folder, "pfPoseData")

    period = float(np.median(np.diff(imu["t"].to_numpy())))
    start = max(d["t"].iloc[0] for d in (imu, cmd, odom, pose))
    end = min(d["t"].iloc[-1] for d in (imu, cmd, odom, pose))
    t = start + period * np.arange(int(np.floor((end - start) / period)) + 1)

    def lin(df, col):
        return np.interp(t, df["t"].to_numpy(), df[col].to_numpy(float))

    def held(col):  # the command's mean over each sample period: at its own time under stid's input
        return interval_means(cmd["t"].to_numpy(), cmd[col].to_numpy(float), t, period)  # (stid.held_command)

    psi = heading_from_quaternion(*(pose[c].to_numpy(float) for c in ("q.x", "q.y", "q.z", "q.w")))

    return pd.DataFrame({
        "t": t - t[0],
        "steer": held("delta"),
        "ay": lin(imu, "ax") * G0,
        "r": lin(imu, "wz") * DEG,
        "vx": lin(odom, "vx"),
        "ax": -lin(imu, "ay") * G0,
        "psi_pf": np.interp(t, pose["t"].to_numpy(), psi),
        "v_cmd": held("V"),
    })


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path, help="a FrictionMaps dataset folder, e.g. DataSets/DS1")
    ap.add_argument("out", type=Path, help="the contract CSV to write")
    args = ap.parse_args(argv)
    df = convert(args.dataset)
    df.to_csv(args.out, index=False, float_format="%.6g")
    print(f"{args.out}: {len(df)} rows, {df['t'].iloc[-1]:.1f} s at {1 / np.median(np.diff(df['t'])):.1f} Hz, "
          f"vx {df['vx'].min():.2f}-{df['vx'].max():.2f} m/s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
