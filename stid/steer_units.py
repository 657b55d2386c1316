"""A steering signal from another tool as the front road-wheel angle [rad].

Loggers record what they have: a servo pulse width [us], a servo command in 0-1 (the
VESC's ``commands/servo/position``, 0.15-0.85 around 0.5304 on an F1TENTH car) or in
+-1. Fitted as radians, such a column gives parameters that are wrong by the
unknown servo gain, with nothing to show it but wide intervals. A column in servo
units is recognised by physics any car obeys and refused until the vehicle file says
how it maps to the road-wheel angle:

- while the car drives straight its road wheels point straight: a road-wheel angle is
  within a trim of ~0 there (a few degrees), a 0-1 command sits near 0.5, a pulse near
  1500 us; and a road-wheel angle turns both ways (its column crosses 0), a command with
  an offset (0-1, percent, ADC counts) need not;
- few RC cars steer their road wheels beyond ~35 deg (0.6 rad; F1TENTH cars: 0.42 rad): a
  column centred at 0 that reaches further is a +-1 command when the kinematics say so (the
  angle the car turned by, L r / vx, against the column: 1 per rad for an angle).

The map: ``[steering] offset, gain`` (command = offset + gain * angle, the VESC's
``steering_angle_to_servo_offset/gain``), or for pulse widths ``center_us, us_per_rad``
(what ``stid calibrate --circle`` writes). The refusal gives the lines to add, with
values estimated from the run's own kinematics (road-wheel angle ~ L r / vx when
cornering gently).
"""

from __future__ import annotations

import numpy as np

from stid.errors import InputError

MAX_ROAD_WHEEL_RAD = 0.6
NOT_RADIANS = 1.0  # rad (57 deg): no road wheel turns so far; a steering signal beyond it is in other units
RAD_GAIN = (1 / 1.5, 1.5)  # the map a column in rad shows from the kinematics (noise, servo and linkage)
STRAIGHT_TRIM_RAD = 0.2  # 11 deg: far beyond any trim, far inside 0.5 of a 0-1 command
PULSE_US = (500.0, 2600.0)  # RC servo pulse widths (1000-2000 us standard, 500-2500 extended)
STRAIGHT_R = 0.05  # rad/s: below this yaw rate, moving, the car drives straight
MOVING_MPS = 1.0
GENTLE_AY = 0.15 * 9.81  # the tyres are linear when cornering gently (as stid calibrate --circle)
LOWPASS_HZ = 1.0  # below a 1:10 car's yaw natural frequency (2-5 Hz): the slow, quasi-steady part


def not_radians(where: str, what: str, peak: float) -> str:
    """The words for a steering angle beyond any road wheel's reach as radians (degrees?)."""
    return (f"{where}: '{what}' reaches {peak:.3g}, which no road wheel turns in rad ({np.degrees(peak):.0f} deg; "
            f"RC cars' steering locks are ~{MAX_ROAD_WHEEL_RAD:g} rad): degrees, or a servo command in other units?")


def road_wheel_angle(x, r, vx, ay, fs, vehicle, where: str, what: str = "steer"):
    """``(angle [rad], notes, warnings)`` from the steering signal ``x`` (on the run's grid).

    Parameters
    ----------
    x : ndarray
        The steering signal as logged.
    r, vx, ay : ndarray
        Yaw rate [rad/s], speed [m/s], lateral acceleration [m/s^2] on the same grid (already
        in SI units), to tell a straight line and to estimate the map.
    fs : float
        Sampling rate of the grid [Hz].
    vehicle : Vehicle or None
        Its ``[steering]`` table holds the declared map.
    where, what : str
        The file and the column or topic, for the messages.
    """
    x = np.asarray(x, float)
    st = (vehicle.raw.get("steering", {}) if vehicle is not None else {}) or {}
    if "gain" in st:
        return (x - float(st["offset"])) / float(st["gain"]), [
            f"{what} is a servo command, turned into the road-wheel angle by the vehicle file's [steering] "
            f"(angle = (command - {st['offset']:g}) / {st['gain']:g})"], []
    centre = _straight_centre(x, r, vx)
    lo, hi = float(np.min(x)), float(np.max(x))
    if PULSE_US[0] <= centre <= PULSE_US[1]:
        if "center_us" in st or "us_per_rad" in st:
            return (x - vehicle.steer_center_us) / vehicle.steer_us_per_rad, [
                f"{what} is a servo pulse width [us], turned into the road-wheel angle by the vehicle file's "
                f"[steering] (centre {vehicle.steer_center_us:g} us, {vehicle.steer_us_per_rad:g} us per rad)"], []
        raise _refused(where, what, f"a servo pulse width in us ({lo:.0f} to {hi:.0f} us, {centre:.0f} us when the "
                                    "car drives straight)", x, r, vx, ay, fs, vehicle, pulse=True)
    one_signed = lo >= 0.0 or hi <= 0.0  # a road-wheel angle turns both ways: it crosses 0
    if abs(centre) > STRAIGHT_TRIM_RAD and one_signed:
        sign = "negated " if centre < 0 else ""
        unit = "0-1 units" if max(abs(lo), abs(hi)) <= 1.0 else "units with an offset (percent? counts?)"
        raise _refused(where, what, f"a {sign}servo command in {unit} ({lo:.3g} to {hi:.3g}, {centre:.3g} when the "
                                    "car drives straight)", x, r, vx, ay, fs, vehicle)
    if STRAIGHT_TRIM_RAD < abs(centre) <= 1.0:
        raise InputError(f"{where}: '{what}' is {centre:+.2f} while the car drives straight: not a road-wheel angle "
                         f"in rad (that is ~0 there); if it is a servo command, declare its map: [steering] offset = "
                         f"{centre:.3g} and gain = the command change per rad")
    peak = float(np.max(np.abs(x)))
    if peak > NOT_RADIANS:
        raise InputError(not_radians(where, what, peak) + "; declare its map: [steering] offset = 0 and gain = "
                         "57.2958 if it is in degrees (the command per rad)")
    if MAX_ROAD_WHEEL_RAD < peak <= 1.0:
        # beyond most steering locks as radians; the kinematics decide: a road-wheel angle in rad
        # has a map of gain ~1 once the understeer is apart, a +-1 command 1 / its full lock
        est = estimate_map(x, r, vx, ay, vehicle.L, fs) if vehicle is not None else None
        if est is not None and est[2] and not RAD_GAIN[0] <= abs(est[1]) <= RAD_GAIN[1]:
            raise _refused(where, what, f"a servo command in +-1 units ({lo:.2f} to {hi:.2f}, beyond most RC cars' "
                                        f"steering lock of ~{MAX_ROAD_WHEEL_RAD:g} rad if it were radians, and "
                                        f"{abs(est[1]):.2f} per rad of the angle the car turned by)",
                           x, r, vx, ay, fs, vehicle)
        if est is None or not est[2]:
            return x, [], [f"'{what}' reaches {peak:.2f} rad, beyond most RC cars' steering lock, and the run does "
                           "not tell whether it is a +-1 command (its speed hardly varied): if it is, declare its "
                           "map in [steering] (offset, gain)"]
    return x, [], []


def _straight_centre(x, r, vx) -> float:
    """The median of ``x`` while moving straight (the whole column's when the run never does)."""
    straight = (np.abs(vx) > MOVING_MPS) & (np.abs(r) < STRAIGHT_R)
    if straight.sum() < 20:
        return float(np.median(x))
    return float(np.median(x[straight]))


def estimate_map(x, r, vx, ay, L: float, fs: float):
    """``(offset, gain, understeer_apart)`` of command = offset + gain * angle, or None when the
    run does not tell.

    In steady cornering the road-wheel angle is L r / vx + K vx r (K: the understeer
    gradient): taking L r / vx alone makes |gain| too large by 1 + K vx^2 (18% on a 1:10 car at
    3 m/s). Regressed on both, K drops out where the speed varied enough to tell the two
    apart (``understeer_apart``). Both sides are low-passed at LOWPASS_HZ first: the yaw
    rate's lag behind a quick steer is not steering geometry.
    """
    from stid.fit import filters

    ok = (np.abs(vx) > MOVING_MPS) & (np.abs(ay) < GENTLE_AY)
    if ok.sum() < 2 * fs / LOWPASS_HZ:
        return None
    sos = filters.butter_lowpass_sos(2, LOWPASS_HZ, fs)
    lp = lambda v: filters.sosfiltfilt(sos, np.asarray(v, float))[ok]  # noqa: E731
    speed = np.where(np.abs(vx) > MOVING_MPS, vx, MOVING_MPS)
    cmd, kin, us = lp(x), lp(L * r / speed), lp(vx * r)
    if np.std(cmd) == 0 or np.std(kin) == 0 or abs(np.corrcoef(cmd, kin)[0, 1]) < 0.7:
        return None
    apart = abs(np.corrcoef(kin, us)[0, 1]) < 0.99
    cols = [np.ones_like(kin), kin] + ([us] if apart else [])
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), cmd, rcond=None)
    return float(coef[0]), float(coef[1]), apart


def _refused(where, what, looks, x, r, vx, ay, fs, vehicle, pulse=False) -> InputError:
    arrays = [np.asarray(v, float) for v in (x, r, vx, ay)]
    est = estimate_map(*arrays, vehicle.L, fs) if vehicle is not None else None
    keys = ("center_us", "us_per_rad") if pulse else ("offset", "gain")
    fmt = "{:.0f}" if pulse else "{:.4g}"
    vals = (fmt.format(est[0]), fmt.format(est[1])) if est else (fmt.format(_straight_centre(x, r, vx)), "?")
    if est is None:
        source = ("the gain is the command change per rad of road-wheel angle, e.g. the VESC's "
                  "steering_angle_to_servo_gain; this run does not tell it")
    else:
        source = ("values estimated from this run's kinematics, road-wheel angle = L r / vx + understeer, when "
                  "cornering gently" + ("" if est[2] else "; the speed hardly varied, so the understeer could not be "
                                        "told apart and |gain| is too large by 1 + K vx^2")
                  + "; on simulated bags they came up to 3-6% off the true map, and the cornering stiffnesses "
                  "fitted with them inherit that error, which no interval holds: 'stid calibrate --circle' or the "
                  "car's own settings give them exactly")
    lines = "\n".join(f"  {k} = {v}" for k, v in zip(keys, vals))
    st = (vehicle.raw.get("steering", {}) if vehicle is not None else {}) or {}
    # a pulse map (what stid calibrate writes for stid-log's pulse widths) is not this command's
    # map: without this the user, whose file has a [steering] table, is told to declare one
    other = (" The vehicle file's [steering] center_us and us_per_rad map a servo pulse width in us (as stid-log "
             "records it), not this command: add offset and gain beside them." if not pulse and
             ("center_us" in st or "us_per_rad" in st) else "")
    return InputError(f"{where}: '{what}' looks like {looks}, not a road-wheel angle in rad: fitted as radians every "
                      f"parameter would be wrong.{other} Declare its map in the vehicle file ({source}):\n"
                      f"  [steering]\n{lines}")
