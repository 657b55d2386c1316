"""What the data's own kinematics say about sensor offsets, before any dynamics.

At the centre of gravity ay = vy' + vx r holds for any rigid body, whatever its tyres
do. Over a stretch of T seconds, vy' averages (vy(T) - vy(0)) / T, which is small
because a car's lateral velocity stays bounded: so mean(ay - vx r) ~ 0 for a car
whose sensors read true, with no model fitted. Offsets of the sensors break it:

    mean(ay_meas - vx r_meas) = bias_ay - bias_r mean(vx)

(a gyro offset alone shows as r - ay/vx ~ bias_r). A steering trim does not break it:
it turns the car, and a turn keeps ay = vx r. So the data bound a named sensor offset
independently of the dynamics fit:

1. the offsets fitted must predict the mean of ay - vx r the data show at every speed;
2. where the data show none, a fitted gyro offset that only an accelerometer offset of
   exactly vx times it hides is what a turn makes, not a sensor: a trim
   (``steer_offset``) explains that residual with one parameter. (Two sensor offsets
   that cancel so at the one speed driven are possible but a coincidence; the fix is a
   second speed, which separates them, see SteerOffset.confused_with.)

At one speed the kinematics give one equation for two offsets: any gyro offset is hidden by
an accelerometer offset of vx times it. A stand-still in the same run separates them: the
loader takes the gyro's zero from it (stid.convert.gyro_zero_from_still), so

3. at one speed, a gyro offset named beyond that zero is at most the gyro's drift since it was taken
   (``GYRO_ZERO_DRIFT``, or more where the run's own stand-stills disagree by more), plus
   the zero's own uncertainty. A larger one belongs to something else (a trim, an
   accelerometer's tilt, the dynamics), not to the gyro.

Each stretch is cut into windows of ``WINDOW_S``: each window's mean of ay - vx r holds
its own vy change over its own length, so their scatter measures that term (and the
noise) from the data, and a run whose speed varies gives one equation per window at
its own speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WINDOW_S = 2.0  # s: several times the lateral velocity's correlation time at scale-car speeds
SPEED_STEP = 1.15  # a new speed group starts 15% above the last one's slowest window (as the evidence's)
Z = 3.0  # the data's mean is held to within 3 standard errors (several speeds, two tests)
# A sensor's scale may be off (ADXL335: 270-330 mV/g at 3 V; the gyro's several percent): in a
# turn that moves mean(ay - vx r) by up to this share of mean(ay) without any offset. The
# consistency test allows it; the "no offset" test does not need it (it only errs toward
# allowing a bias).
SCALE_TOL = 0.1
# How far a MEMS gyro's zero can move within one run after it was taken at a stand-still of that
# run: its temperature coefficient times the run's temperature change. Consumer MEMS gyros state
# 0.01-0.08 deg/s per K (the BMI160 of the VESC 6 the upper end of that; its datasheet and the
# LISY300AL's could not be read here: unverified), and a board within one run of minutes warms
# by well under 10 K (a motor controller's IMU sits on the power stage: the high end). 0.08 deg/s/K
# times 10 K. Measured on the real log (tests/fixtures/real): the stand-stills at the start and the
# end of ds3, two minutes apart, differ by 0.02 deg/s, ds4's by 0.05 deg/s.
GYRO_ZERO_DRIFT = float(np.radians(0.8))  # rad/s


@dataclass
class SpeedGroup:
    """The kinematic offset of the windows at one speed."""

    speed: float  # m/s, time-weighted mean over the windows
    k: float  # m/s^2, mean of ay - vx r
    se: float  # m/s^2, its standard error (the windows' scatter)
    mean_ay: float  # m/s^2
    seconds: float

    def tol(self, scale: bool) -> float:
        return Z * self.se + (SCALE_TOL * abs(self.mean_ay) if scale else 0.0)


def _windows(stretches, k_gyro: float = 0.0):
    """(speed, mean of ay - vx r, mean ay, seconds) per window of every stretch, over its
    valid samples; the yaw rate corrected for a fitted gyro scale."""
    out = []
    for s in stretches:
        n = max(1, int(round(WINDOW_S / s.dt)))
        ok = np.ones(len(s.t), bool) if s.valid is None else np.asarray(s.valid, bool)
        vx = np.asarray(s.vx_series, float)
        d = s.ay - vx * s.r / (1.0 + k_gyro)
        for a in range(0, len(s.t) - n + 1, n):
            m = ok[a:a + n]
            if m.sum() < 0.8 * n:
                continue
            out.append((float(np.mean(vx[a:a + n][m])), float(np.mean(d[a:a + n][m])),
                        float(np.mean(s.ay[a:a + n][m])), float(m.sum() * s.dt)))
    return out


def speed_groups(stretches, k_gyro: float = 0.0) -> list[SpeedGroup]:
    """The windows grouped by speed, each group's mean of ay - vx r with its standard error."""
    w = sorted(_windows(stretches, k_gyro))
    groups, start = [], None
    for row in w:
        if start is None or row[0] > SPEED_STEP * start:
            groups.append([])
            start = row[0]
        groups[-1].append(row)
    # a group of one or two windows has no scatter of its own: the pooled scatter of all stands in
    resid = [row[1] - np.mean([x[1] for x in g]) for g in groups for row in g if len(g) > 1]
    pooled = float(np.std(resid)) if len(resid) > 2 else float("inf")
    out = []
    for g in groups:
        v, k, ay, sec = (np.array(c) for c in zip(*g))
        sd = float(np.std(k, ddof=1)) if len(g) >= 3 else pooled
        out.append(SpeedGroup(float(np.average(v, weights=sec)), float(np.average(k, weights=sec)),
                              sd / np.sqrt(len(g)), float(np.average(ay, weights=sec)), float(sec.sum())))
    return out


def _dps(x: float) -> str:
    return f"{np.degrees(x):+.2f} deg/s"


def sensor_bias_check(result, stretches) -> str:
    """Why the kinematics rule out the sensor offsets of ``result`` (a fit with ``bias_r`` and
    ``bias_ay``), or "" when they agree."""
    p = result.all_params()
    b_r, b_ay = p["bias_r"], p["bias_ay"]
    groups = [g for g in speed_groups(stretches, p.get("k_gyro", 0.0)) if np.isfinite(g.se)]
    if not groups:
        return ""
    for g in groups:  # 1. the offsets must predict what the data show at every speed
        want = b_ay - b_r * g.speed
        if abs(g.k - want) > g.tol(scale=True):
            return (f"the kinematics rule it out: at {g.speed:.1f} m/s the data's r - ay/vx averages "
                    f"{_dps(-g.k / g.speed)} (+-{np.degrees(g.tol(True) / g.speed):.2f}), the offsets fitted "
                    f"(gyro {_dps(b_r)}, accelerometer {b_ay:+.3f} m/s^2) make it {_dps(-want / g.speed)}; "
                    "a car's motion keeps ay = vy' + vx r, so these offsets are not the sensors'")
    quiet = all(abs(g.k) <= g.tol(scale=False) for g in groups)
    seen = [g for g in groups if abs(b_r) * g.speed > 2.0 * g.tol(scale=True)]
    if quiet and seen:  # 2. offsets that cancel as a turn's do: a trim, not two sensors
        g = max(seen, key=lambda g: g.seconds)
        return (f"the kinematics see no sensor offset (r - ay/vx averages {_dps(-g.k / g.speed)} "
                f"+-{np.degrees(g.tol(False) / g.speed):.2f} at {g.speed:.1f} m/s) while the fit needs a gyro "
                f"offset of {_dps(b_r)}, hidden only by an accelerometer offset of vx times it: that is what a "
                "turn makes, and a steering offset (steer_offset) explains it with one parameter")
    # 3. at one speed only: there the kinematics cannot tell a gyro offset from an accelerometer's,
    # the stand-still can. At two speeds or more, 1. has already weighed both offsets against the
    # data, and a drift larger than GYRO_ZERO_DRIFT (a figure not checked against this gyro's
    # datasheet) must not overrule them.
    zeroed = _zero_allowance(stretches) if len(groups) == 1 else None
    if zeroed is not None and abs(b_r) > zeroed[0]:  # beyond the drift of a zero taken in the run
        allowed, zero = zeroed
        return (f"the gyro was zeroed at {zero['source']} ({_dps(zero['value'])} +-{np.degrees(zero['stderr']):.2f} "
                f"over {zero['still_s']:.1f} s): an offset left after it is at most its drift since, "
                f"{np.degrees(allowed):.2f} deg/s, while the fit needs {_dps(b_r)} beyond the zero: that offset "
                "is not the gyro's (the kinematics at one speed take a gyro offset for an accelerometer's; the "
                "stand-still does not)")
    return ""


def _zero_allowance(stretches):
    """(largest gyro offset beyond the zero the drift allows [rad/s], the zero) when every
    stretch's gyro was zeroed at a stand-still of its own run, else None: the loosest of the
    stretches' (the drift, the zero's 3 standard errors, the spread of the run's own stand-stills)."""
    zeros = [getattr(s, "gyro_zero", None) for s in stretches]
    if not zeros or any(z is None for z in zeros):
        return None
    allowed = [GYRO_ZERO_DRIFT + Z * z["stderr"] + z.get("drift_seen", 0.0) for z in zeros]
    k = int(np.argmax(allowed))
    return allowed[k], zeros[k]


CHECKS = {"sensor_bias": sensor_bias_check}


def kinematic_veto(effect: str, result, stretches) -> str:
    """Why the data's kinematics rule out ``effect`` as fitted in ``result`` ("" if they do not,
    or the effect has no kinematic check)."""
    check = CHECKS.get(effect)
    return check(result, stretches) if check is not None else ""
