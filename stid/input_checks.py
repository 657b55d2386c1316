"""Checks that a run's numbers mean what the import contract says (DESIGN.md): time in
seconds, ay in m/s^2, r in rad/s, steer, r and ay positive to the left (ISO 8855).

A wrong unit or sign does not make a file unreadable, it makes every fitted number
wrong; so these checks test the data against physics that holds for any car, and a
failed check is an ``InputError`` that names the column and the fix.
"""

from __future__ import annotations

import math

import numpy as np

from stid.errors import InputError

G = 9.81

# -- time -----------------------------------------------------------------------

# Loggers for vehicle dynamics sample at 20 Hz-20 kHz: steps of 0.05-50 ms.
LOGGER_STEP_S = (5e-5, 0.05)
# A step of 0.5 s (2 Hz) or longer cannot be seconds of a dynamics log: its Nyquist
# frequency (1 Hz) lies below the yaw natural frequency of any car (~1 Hz for a
# passenger car, 2-5 Hz for a 1:8 RC car), so nothing of the dynamics is in it.
SLOWEST_STEP_S = 0.5
_TIME_UNITS = ((1e3, "milliseconds", "1000"), (1e6, "microseconds", "1e6"), (1e9, "nanoseconds", "1e9"))


def check_time_steps(where: str, t: np.ndarray) -> None:
    """Raise InputError when the time column is not in seconds.

    Parameters
    ----------
    where : str
        The file, for the message.
    t : ndarray
        The time column as read, increasing.
    """
    step = float(np.median(np.diff(t)))
    if step < SLOWEST_STEP_S:
        return
    for scale, unit, divisor in _TIME_UNITS:
        if LOGGER_STEP_S[0] <= step / scale < LOGGER_STEP_S[1]:
            raise InputError(f"{where}: 't' steps by {step:.4g} per sample, which would be {1 / step:.3g} Hz in "
                             f"seconds but {scale / step:.4g} Hz in {unit}: 't' looks like {unit}; "
                             f"divide it by {divisor} (the CSV contract wants seconds)")
    raise InputError(f"{where}: 't' steps by {step:.4g} s per sample ({1 / step:.3g} Hz): too slow to hold "
                     f"any vehicle dynamics, and no usual time unit explains it; 't' must be in seconds, "
                     "sampled at 20 Hz or faster")


# -- kinematics: ay = dvy/dt + vx r ----------------------------------------------

# Over the slow part of a run, ay = dvy/dt + vx*r with dvy/dt the derivative of a
# bounded signal (vy stays within a few degrees of body slip times vx), so it drops
# out below the yaw and side-slip dynamics: the least-squares gain of ay on vx*r is ~1
# whatever the tyres, mass or inertia. Both are low-passed at LOWPASS_HZ, below the
# yaw natural frequency of any car, where dvy/dt is small.
LOWPASS_HZ = 0.5
MOVING_MPS = 1.0  # below ~1 m/s wheel-speed vx is coarse and there is little to check
# Enough cornering to tell, judged on the slow parts themselves:
# - ay must follow vx*r: |corr| >= MIN_CORRELATION. What else moves a slow ay (road
#   slope changes, pitch tilting the accelerometer under braking, offset drift,
#   vibration leaking through) lowers the correlation, never the units. Units and
#   signs do not change |corr|, so this cannot hide a unit error. At 0.7, with ~30
#   independent slow samples in a 30 s run, the gain's standard error is ~20%: far
#   inside the factor-2 band around 1, and unit errors are factors of 3.6 to 570.
# - the slow part of vx*r must vary by MIN_CORNERING (m/s^2 rms, 0.01 g) or more: 30x
#   the gyro noise left after the low-pass (LISY300AL ~0.4 deg/s rms over 88 Hz ->
#   ~0.003 m/s^2 below 0.5 Hz at 5 m/s), so a high correlation is not one of noise.
# Offsets (accelerometer zero-g up to 1.5 m/s^2, gyro bias times a steady vx) drop out
# with the intercept of the regression.
MIN_CORNERING = 0.1
MIN_CORRELATION = 0.7
MIN_MOVING_S = 10.0  # five periods of LOWPASS_HZ, so dvy/dt averages out
# Gain of ay on vx*r a consistent run can show: side-slip dynamics left after the
# low-pass 0.8-1.2 (linear single-track model, 2-15 m/s, random steer to 8 Hz);
# sensor sensitivity +-10% each (ADXL335, LISY300AL datasheets); accelerometer tilt
# from body roll up to +10%; wheel-speed vx off by slip and tyre radius up to +-10%.
# Their worst products are 0.58 and 1.76. The nearest unit errors lie outside this
# range: vx in km/h gives 0.28, ay in g 0.10, r in deg/s 0.017, and a flipped sign
# makes the gain negative.
CONSISTENT_GAIN = (0.5, 2.0)
# Named unit errors: the gain they produce (|gain| within a factor 1.6 of it).
_UNIT_ERRORS = (
    (1 / G, "'ay' looks like it is in g", "multiply it by 9.81 to get m/s^2"),
    (math.pi / 180, "'r' looks like it is in deg/s", "multiply it by pi/180 to get rad/s"),
    (math.pi / 180 / G, "'ay' and 'r' look like they are in g and deg/s",
     "convert ay to m/s^2 (x 9.81) and r to rad/s (x pi/180)"),
    (1 / 3.6, "'vx' looks like it is in km/h", "divide it by 3.6 to get m/s"),
)
_UNIT_MATCH = 1.6


BACKWARDS_SHARE = 0.8  # of the time a run moves faster than MOVING_MPS: a speed sign the other way


def _mostly_backwards(run, source: str) -> str | None:
    """The words for a run that would reverse for most of its driving: a speed whose sign is the
    other way (a VESC's speed_to_erpm_gain negated, an odometry in another frame), not a car that
    drives backwards. Taken as it is, the kinematic check blamed the IMU's axes, and its fix led to
    the steering's sign and then to "no stretch of driving" (a trial user's negated odometry)."""
    vx = np.asarray(run.vx, float)
    moving = np.abs(vx) > MOVING_MPS
    if moving.sum() < 2 * run.fs or np.mean(vx[moving] < 0) < BACKWARDS_SHARE:
        return None
    where = run.meta.get("source", run.name)
    share = 100 * float(np.mean(vx[moving] < 0))
    fix = {"csv": "negate vx (ISO 8855: forward positive)",
           "ros": "the odometry's twist.linear.x is negative while the car drives forward: a VESC "
                  "speed_to_erpm_gain of the wrong sign, or an odometry not in the car's frame (REP 105); "
                  "[ros] speed_scale = -1 in the vehicle file reads it"}.get(source, "check the wheel-speed sensor's calibration")
    return (f"{where}: the forward speed is negative for {share:.0f}% of the time the car moves faster than "
            f"{MOVING_MPS:g} m/s: the car would be reversing nearly all the time; its sign is the other way: {fix}")


def check_kinematics(run, source: str = "csv") -> None:
    """Raise InputError when ay, r and steer disagree in unit or sign.

    Checks ay against vx*r (their ratio is ~1 for any car), and the sign of r against
    steer (a car below its critical speed turns the way it is steered). Skipped when
    the run has too little cornering to tell; a CSV run then gets a warning.

    Parameters
    ----------
    run : Run
        Uniformly sampled, SI units as loaded.
    source : str
        ``"csv"`` (the user chose units and signs: name the column to fix) or
        ``"mcap"`` (stid converted them: point at the sensor calibration).
    """
    backwards = _mostly_backwards(run, source)
    if backwards:
        raise InputError(backwards)
    est = _kinematic_gains(run)
    if isinstance(est, str):
        if source in ("csv", "ros"):
            run.warn(f"the units and signs of ay and r could not be checked against vx*r: {est}")
        return
    gain, steer_sign = est
    where = run.meta.get("source", run.name)
    lo, hi = CONSISTENT_GAIN
    if lo <= gain <= hi:
        if steer_sign < 0:
            raise InputError(_steer_message(where, source))
        scale = scale_mismatch(run, source)
        if scale:
            run.warn(scale)
        return
    if -hi <= gain <= -lo:
        raise InputError(_sign_message(where, source, steer_sign))
    for ratio, what, fix in _UNIT_ERRORS:
        if abs(math.log(abs(gain) / ratio)) < math.log(_UNIT_MATCH):
            if source == "ros" and gain > 0 and what in _ROS_UNIT_FIX:
                raise InputError(f"{where}: ay is {gain:.3g} x vx*r where physics wants ~1: {what}; "
                                 f"{_ROS_UNIT_FIX[what]}")
            if source == "csv":
                if gain < 0:
                    flipped = {1: "'ay'", -1: "'r'"}.get(steer_sign, "'ay' or 'r'")
                    fix += f", and negate {flipped} (its sign is the SAE one; ISO 8855: left turns positive)"
                raise InputError(f"{where}: ay is {gain:.3g} x vx*r where physics wants ~1: {what}; {fix}")
            break
    raise InputError(f"{where}: ay is {gain:.3g} x vx*r where physics wants ~1 (ay = dvy/dt + vx*r): a unit or "
                     "sign is wrong; " + {"csv": "the CSV contract wants ay in m/s^2, r in rad/s, vx in m/s, left "
                                                 "positive",
                                          "ros": "check the vehicle file's [ros] imu_axes, accel_unit and gyro_unit "
                                                 "(docs/ros.md)"}.get(source, "check the sensor calibration in the "
                                                                              "vehicle file and the HELLO"))


# -- scales: units right, and still ay != vx*r -------------------------------------

# The units check above accepts any gain within CONSISTENT_GAIN: it looks for factors of 3.6
# to 570. Inside that band a gain far from 1 is a scale that is wrong, not a unit: a wheel
# speed that counts wheel spin or a wrong wheel radius, or a sensor's sensitivity. What a
# consistent run can show (the product of the bounds below):
# - the accelerometer's and the gyro's sensitivity, +-10% each (ADXL335 270-330 mV/g;
#   LISY300AL the same order; a digital MEMS IMU is tighter): 0.82-1.22 for their ratio;
# - the side-slip dynamics left in the slow part, dvy/dt correlated with vx*r: with the
#   band at SCALE_FV / (the run's 90th-percentile speed) Hz, a linear single track with
#   normalised cornering stiffness 4-11.6 /rad (a 1:8 and a 1:10 car, 2-8 m/s, random steer
#   to 3 Hz) gave gains 0.948-1.048: 0.95-1.05;
# - body roll tilting the accelerometer toward the turn, g sin(phi) on ay: up to +10%.
# The wheel speed has no tolerance here: wheel spin and the radius are what this looks for.
SCALE_FV = 4.0  # m/s * Hz: the band times the speed within which dvy/dt stays within 5%
SCALE_BAND_HZ = (0.25, 2.0)
SCALE_TOLERANCE = (0.9 / 1.1 * 0.95, 1.1 / 0.9 * 1.05 * 1.1)  # 0.777, 1.411
SCALE_Z = 3.0  # beyond the tolerance by 3 standard errors of the gain


def scale_gain(run):
    """(gain of ay on vx*r, its standard error, band [Hz]) over the moving part, low-passed in a
    band that scales with the speed (SCALE_FV), or None when the run does not tell (too little
    moving, too little cornering). The standard error counts one independent sample per half
    period of the band."""
    from stid.fit import filters

    vx = np.asarray(run.vx, float)
    moving = np.abs(vx) > MOVING_MPS
    fs = run.fs
    if moving.sum() / fs < MIN_MOVING_S or not all(np.all(np.isfinite(v)) for v in (run.ay, run.r, vx)):
        return None
    fc = float(np.clip(SCALE_FV / np.percentile(np.abs(vx[moving]), 90), *SCALE_BAND_HZ))
    fc = min(fc, 0.4 * fs)
    sos = filters.butter_lowpass_sos(2, fc, fs)
    edge = int(fs / fc)
    moving[:edge] = moving[-edge:] = False
    if moving.sum() < 4:
        return None
    # both at once, a column each (the same numbers as one by one, in less time)
    x, y = filters.sosfiltfilt(sos, np.column_stack([vx * run.r, run.ay]))[moving].T
    xc, yc = x - x.mean(), y - y.mean()
    if float(np.sqrt(np.mean(xc ** 2))) < MIN_CORNERING:
        return None
    gain = float(np.sum(xc * yc) / np.sum(xc ** 2))
    e = yc - gain * xc
    n_eff = max(moving.sum() / fs * 2 * fc, 3.0)
    se = float(np.sqrt(np.sum(e ** 2) / (len(e) - 2) / np.sum(xc ** 2) * len(e) / n_eff))
    return gain, se, fc


def scale_mismatch(run, source: str = "csv") -> str:
    """A warning when ay and vx*r agree in unit and sign but not in size: farther from 1 than
    the sensors' sensitivities and the dynamics allow (SCALE_TOLERANCE) by SCALE_Z standard
    errors; "" otherwise. Names what makes each side read wrong."""
    est = scale_gain(run)
    if est is None:
        return ""
    gain, se, fc = est
    lo, hi = SCALE_TOLERANCE
    if lo - SCALE_Z * se <= gain <= hi + SCALE_Z * se:
        return ""
    radius = {"csv": "the odometry's wheel radius or gain", "ros": "the odometry's wheel radius or ERPM gain"}.get(
        source, "the wheel radius in the vehicle file")
    if gain < lo:
        why = (f"vx reads high (wheel spin: a driven wheel's speed counts its spin; {radius} too large), or the "
               "gyro reads high / the accelerometer low (their scale)")
    else:
        why = (f"vx reads low (wheels locked or sliding under braking; {radius} too small), or the gyro reads "
               "low / the accelerometer high (their scale)")
    return (f"ay is {gain:.2f} +- {se:.2f} x vx*r over the slow part (below {fc:.2g} Hz, moving), where a car "
            f"whose speed and sensors read true shows {lo:.2f}-{hi:.2f} (ay = dvy/dt + vx*r; the sensors' "
            f"tolerances and the side-slip dynamics): {why}. Every fitted value scales with the speed: "
            "check the speed against another measure (a lap time, a lidar or GPS track)")


# a ROS IMU in the units the VESC driver sends: the [ros] key that says so
_ROS_UNIT_FIX = {"'r' looks like it is in deg/s": "add gyro_unit = \"deg/s\" to the vehicle file's [ros]",
                 "'ay' looks like it is in g": "add accel_unit = \"g\" to the vehicle file's [ros]",
                 "'ay' and 'r' look like they are in g and deg/s":
                     "add accel_unit = \"g\" and gyro_unit = \"deg/s\" to the vehicle file's [ros]"}


def ay_gain(run):
    """The least-squares gain of ay on vx*r over the run's slow part (~1 for consistent
    units and signs), or a sentence saying why the run does not tell."""
    est = _kinematic_gains(run)
    return est if isinstance(est, str) else est[0]


def _kinematic_gains(run):
    """(gain of ay on vx*r, sign of r against steer: +1, -1 or 0), or why not decidable."""
    from stid.fit import filters

    fs = run.fs
    vx = np.asarray(run.vx, float)
    moving = np.abs(vx) > MOVING_MPS
    if not all(np.all(np.isfinite(v)) for v in (run.ay, run.r, run.steer, vx)):
        return "the signals have gaps (NaN)"
    if moving.sum() / fs < MIN_MOVING_S + 2 / LOWPASS_HZ:
        return f"under {MIN_MOVING_S:g} s above {MOVING_MPS:g} m/s"
    sos = filters.butter_lowpass_sos(2, LOWPASS_HZ, fs)
    # one period of LOWPASS_HZ at either end is the filter's start-up: left out
    moving[: int(fs / LOWPASS_HZ)] = moving[-int(fs / LOWPASS_HZ):] = False
    # all four at once, a column each (the same numbers as one by one, in less time)
    x, y, s, rr = filters.sosfiltfilt(sos, np.column_stack([vx * run.r, run.ay, vx * run.steer, run.r]))[moving].T
    xc, yc = x - x.mean(), y - y.mean()
    spread = float(np.sqrt(np.mean(xc ** 2)))
    if spread < MIN_CORNERING:
        return f"too little cornering (slow part of vx*r varies by {spread:.2g} m/s^2 rms, below {MIN_CORNERING:g})"
    corr = float(np.sum(xc * yc) / np.sqrt(np.sum(xc ** 2) * np.sum(yc ** 2)))
    if abs(corr) < MIN_CORRELATION:
        return f"ay follows vx*r only weakly (correlation {corr:.2f})"
    gain = float(np.sum(xc * yc) / np.sum(xc ** 2))
    # r against vx*steer: positive for a car below its critical speed, at any steering ratio
    sc, rc = s - s.mean(), rr - rr.mean()
    den = np.sqrt(np.sum(sc ** 2) * np.sum(rc ** 2))
    c = float(np.sum(sc * rc) / den) if den > 0 else 0.0
    steer_sign = 0 if abs(c) < MIN_CORRELATION else (1 if c > 0 else -1)
    return gain, steer_sign


# A flipped sign is an error, not a warning: the ay/vx*r sign is kinematics and holds
# for any car. The steer/r sign holds below the critical speed and without counter-
# steer (drifting); if either is violated the linear single-track model does not
# describe the run either, so in every case a fit would be nonsense.

def _sign_message(where, source, steer_sign) -> str:
    if source == "ros":
        return (f"{where}: the yaw rate and the lateral acceleration have opposite signs (ay ~ -vx*r): the IMU's "
                "axes are declared wrong; fix [ros] imu_axes in the vehicle file (docs/ros.md)")
    if source != "csv":
        return (f"{where}: the yaw rate and the lateral acceleration have opposite signs (ay ~ -vx*r); "
                "check how the sensor board is mounted (gyro or accelerometer upside down?)")
    if steer_sign < 0:
        return (f"{where}: 'r' has the opposite sign to ay/vx and to steer: a z-down (SAE) yaw rate? "
                "negate r (ISO 8855: left turns positive)")
    if steer_sign > 0:
        return (f"{where}: 'ay' has the opposite sign to vx*r and to steer: y to the right (SAE)? "
                "negate ay (ISO 8855: left positive)")
    return (f"{where}: 'ay' and 'r' have opposite signs (ay ~ -vx*r): one of them is in the SAE convention "
            "(y right, z down); negate it (ISO 8855: left turns positive)")


def _steer_message(where, source) -> str:
    if source == "ros":
        return (f"{where}: the car turns right when steered left (r against steer): the steering command's sign is "
                "the other way; for a servo command negate [steering] gain, for an AckermannDrive angle published "
                "positive right set [ros] steering_scale = -1, for an IMU mounted upside down fix [ros] imu_axes")
    if source != "csv":
        return (f"{where}: the car turns right when steered left (r against steer): the steering calibration "
                "has the wrong sign; negate us_per_rad in the vehicle file's [steering]")
    return (f"{where}: 'steer' has the opposite sign to r and ay: steer positive to the right? negate steer "
            "(ISO 8855: left positive; if the car was drifting with counter-steer, the single-track model "
            "does not apply to this run)")
