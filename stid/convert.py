"""Counts -> SI: datasheet defaults from the HELLO content, refined by the
vehicle file's [sensors] (written by ``stid calibrate``), and the per-run gyro
bias from still stretches."""

from __future__ import annotations

import math

import numpy as np

from host import units
from stid import segments
from stid.held_command import interval_means
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


# The hall speed is zero until the wheel has turned two pulses (a speed needs two edges): the
# car already moves before, and with a steering trim, which every RC car has, it already yaws.
# On the simulated reference car (one magnet, 0.28 m a pulse) the speed appeared 0.95 s after
# the start; a trim of 0.025 rad then moved the gyro's zero by 0.47 deg/s (0.008 rad/s), which
# diagnose named as a sensor offset. From rest at constant acceleration a the two pulses take
# sqrt(4 p / a): 1 s covers a > 1.1 m/s^2 (slower starts yaw less in that time).
START_LOOKBACK_S = 1.0


# A car standing still does not turn: its yaw rate is the gyro's zero and noise. Where the speed
# reads zero while the yaw rate, low-passed at STILL_LOWPASS_HZ (a nitro engine's vibration is far
# above it), moves by more than STILL_R_SPAN, the speed sensor failed, not the car stopped (a hall
# magnet or wire, an odometry that stalled). A stretch of random steer at 4 m/s with 6 s of its
# wheel speed at zero gave a gyro zero of -0.9 deg/s, which diagnose named as a gyro offset.
STILL_LOWPASS_HZ = 2.0
STILL_R_SPAN = 0.1  # rad/s (5.7 deg/s) peak to peak; a gyro at rest moves ~1 deg/s there (noise and drift)
STILL_EDGE_S = 0.5  # judged without the ends of a stand-still: the filter smears the stop into them


def turning_while_still(r: np.ndarray, vx: np.ndarray, fs: float) -> list:
    """``(start, stop, span)`` of each stretch where the speed says the car stands still and the
    yaw rate (low-passed) moves by ``span`` > STILL_R_SPAN [rad/s]: the car drove there."""
    mask = segments.still_mask(vx, fs)
    if not mask.any() or fs <= 2 * STILL_LOWPASS_HZ:
        return []
    from stid.fit import filters

    r = np.asarray(r, float)
    lp = filters.sosfiltfilt(filters.butter_lowpass_sos(2, STILL_LOWPASS_HZ, fs), np.nan_to_num(r))
    out = []
    edge = int(STILL_EDGE_S * fs)
    for a, b in segments.runs_of(mask, 1):
        core = lp[a + edge:b - edge] if b - a > 3 * edge else lp[a + (b - a) // 3:b - (b - a) // 3]
        span = float(np.ptp(core)) if len(core) else 0.0
        if span > STILL_R_SPAN:
            out.append((a, b, span))
    return out


def speed_dropout_words(r: np.ndarray, vx: np.ndarray, fs: float, t0: float = 0.0, found=None) -> str | None:
    """A warning for the stretches ``turning_while_still`` finds (``found``, when the caller has
    them), or None."""
    found = turning_while_still(r, vx, fs) if found is None else found
    if not found:
        return None
    zero = np.abs(np.asarray(vx, float)) < 0.05  # (the whole reading, not the core still_mask keeps)
    spans = []
    for a, b, span in found[:3]:
        while a > 0 and zero[a - 1]:
            a -= 1
        while b < len(zero) and zero[b]:
            b += 1
        spans.append(f"{t0 + a / fs:.1f}-{t0 + b / fs:.1f} s (the yaw rate moving by {span:.2f} rad/s)")
    where = ", ".join(spans) + (" and more" if len(found) > 3 else "")
    return (f"the speed reads zero while the car turns at {where}: the speed sensor failed there (a hall magnet "
            "or its wire, a stalled odometry), the car did not stop; not taken as standing still (the gyro's zero "
            "comes from the rest) and, slower than the fit's speed, out of the fit")


def still_samples(vx: np.ndarray, fs: float, lookback_s: float = START_LOOKBACK_S, r=None,
                  turning=None) -> np.ndarray:
    """True where the car stands still, less the last ``lookback_s`` before the speed first
    shows motion (a hall sensor's: it needs two pulses; a motor controller's speed, as a ROS
    bag's odometry has it, sees motion at once): the samples a gyro's zero is taken from.
    With the yaw rate ``r``, without the stretches where the car turned (turning_while_still;
    ``turning``: those stretches, when the caller has them)."""
    mask = segments.still_mask(vx, fs)
    if r is not None:
        for a, b, _ in (turning_while_still(r, vx, fs) if turning is None else turning):
            mask[a:b] = False
    back = int(lookback_s * fs)
    for a, b in segments.runs_of(mask, 1):
        if b < len(mask):  # the car drives off after this stretch
            mask[max(a, b - back):b] = False
    return mask


def gyro_bias_from_still(r: np.ndarray, vx: np.ndarray, fs: float, lookback_s: float = START_LOOKBACK_S):
    """Mean yaw rate while standing still (``still_samples``), or None when the run never
    stands still for 0.5 s."""
    zero = gyro_zero_from_still(r, vx, fs, lookback_s)
    return None if zero is None else zero["value"]


def gyro_zero_from_still(r: np.ndarray, vx: np.ndarray, fs: float, lookback_s: float = START_LOOKBACK_S,
                         turning=None):
    """The gyro's zero from the run's stand-still, with what it rests on, or None when the run
    never stands still for 0.5 s:

    - ``value`` [rad/s], the mean yaw rate while standing still (``still_samples``);
    - ``stderr`` [rad/s], its standard error (the samples' scatter about their own stand-still's
      mean, over the number of independent ones: the integrated autocorrelation time counts a
      filtered gyro's correlated noise once);
    - ``still_s`` [s], how long the car stood still;
    - ``drift_seen`` [rad/s], how far apart the zeros of the run's separate stand-stills of 0.5 s
      or more lie (0 with one): the drift the run itself shows between them.

    An offset left after this zero is the gyro's drift since (stid.analysis.kinematics).
    ``turning``: turning_while_still's stretches, when the caller has them."""
    from stid.stats import tau_int

    mask = still_samples(vx, fs, lookback_s, r=r, turning=turning)
    n = int(mask.sum())
    if n < 0.5 * fs:
        return None
    r = np.asarray(r, float)
    # each stand-still about its own mean: how far apart they lie is drift_seen, not noise
    scatter = np.concatenate([r[a:b] - np.mean(r[a:b]) for a, b in segments.runs_of(mask, 1)])
    tau = tau_int(scatter, max(1, min(n // 4, int(fs))))
    pieces = [float(np.mean(r[a:b])) for a, b in segments.runs_of(mask, max(1, int(0.5 * fs)))]
    return {"value": float(np.mean(r[mask])), "stderr": float(np.std(scatter) * np.sqrt(tau / n)),
            "still_s": n / fs, "drift_seen": float(np.ptp(pieces)) if len(pieces) > 1 else 0.0}


def zero_from_stand_still(run, fs: float | None = None, lookback_s: float = START_LOOKBACK_S) -> dict | None:
    """Every loader's step: the gyro zero of ``run`` from its own stand-still (gyro_zero_from_still),
    recorded (set_gyro_zero; not yet taken off r), and a warning on the run where its speed reads
    zero while it turns (speed_dropout_words). ``fs``: the run's, when the caller has it."""
    fs = run.fs if fs is None else fs
    turning = turning_while_still(run.r, run.vx, fs)
    zero = gyro_zero_from_still(run.r, run.vx, fs, lookback_s, turning=turning)
    set_gyro_zero(run, zero, "this run's stand-still")
    dropout = speed_dropout_words(run.r, run.vx, fs, float(run.t[0]), found=turning)
    if dropout:
        run.warn(dropout)
    return zero


def set_gyro_zero(run, zero: dict | None, source: str) -> None:
    """Record the gyro zero taken off ``run.r`` (gyro_zero_from_still; None: none was):
    ``meta["gyro_bias"]`` its value, ``meta["gyro_zero"]`` the whole record and where it is from,
    which bounds any gyro offset a fit may name beyond it (stid.analysis.kinematics)."""
    run.meta["gyro_bias"] = None if zero is None else zero["value"]
    run.meta["gyro_zero"] = None if zero is None else {**zero, "source": source}


STEER_T_UNKNOWN = 0xFFFFFFFF  # a v1 record: the pulse's time was not logged


def steer_at_servo_times(t_mcu_us: np.ndarray, t_raw_us: np.ndarray, steer_us: np.ndarray,
                         steer_t_us: np.ndarray, vehicle: Vehicle, mod: int, grid_us: np.ndarray,
                         step_us: float):
    """The steering command as the servo received it, on the sample grid ``grid_us``.

    The servo takes each command at its pulse's falling edge and holds it until the
    next: the road wheel is driven by a staircase whose steps sit at the edges. A
    sample records the latest pulse *at the sample instant*, which places every step
    up to one sample period late (on average half a period, and a fixed amount when
    pulses and sampling happen to be phase-locked); yaw inertia moves ~5% per ms of
    steer timing. Protocol v2 logs each pulse's falling-edge time, so the staircase
    is rebuilt exactly and each grid value is its mean over the sample period centred
    on the grid point: a symmetric (delay-free) average that the models'
    first-order-hold input represents without a timing error.

    Returns (steer [rad] or NaN where no pulse was received, True when edge times
    were used).
    """
    us = np.asarray(steer_us, float)
    f, w = logged_pulses(t_mcu_us, t_raw_us, steer_us, steer_t_us, mod)
    if not len(f):
        return None, False
    c = (w - vehicle.steer_center_us) / vehicle.steer_us_per_rad
    f, c = _fill_lost_pulses(f, c, receiver_period_us(f - w))
    g = np.asarray(grid_us, float)
    steer = interval_means(f, c, g, float(step_us))
    # no pulse for longer than the receiver's timeout at a sample: NaN there, as before
    no_pulse = np.interp(g, np.asarray(t_mcu_us, float), (~(us > 0)).astype(float)) > 0.5
    return np.where(no_pulse, np.nan, steer), True


RECEIVER_PERIOD_MIN_US = 2500  # the fastest receivers' frames: 400 Hz
MAX_FILLED = 10  # pulses put back in one hole; a longer one is the receiver off, not pulses lost


def receiver_period_us(rise: np.ndarray) -> float | None:
    """The receiver's frame period [us] from the rising edges of the pulses the records
    carry (falling edge less width: the receiver's own clock, whatever the commands), or None.

    A record carries only the latest pulse at its instant: at a sample rate below the
    receiver's frame rate (a surface receiver at 333 Hz, the firmware at 100 Hz) the pulses
    logged are 3 or 4 frames apart, never one. Every gap is still a whole number of frames:
    the period is the largest one of which 95% of the gaps (within 2% of a period or 30 us)
    are whole multiples, found by dividing the shortest gap by 1, 2, 3, ... A receiver
    phase-locked to the sampler (every gap the same multiple) cannot be told from a slower
    one by its edges alone."""
    d = np.diff(np.sort(np.asarray(rise, np.int64))).astype(float)
    d = d[d > 0]
    if len(d) < 8:
        return None
    base = float(np.percentile(d, 2))
    for n in range(1, 9):
        period = base / n
        if period < RECEIVER_PERIOD_MIN_US:
            return None
        k = np.round(d / period)
        fits = (k >= 1) & (np.abs(d - k * period) <= max(0.02 * period, 30.0))
        if fits.mean() >= 0.95:
            near = fits & (k <= MAX_FILLED + 1)
            return float(np.sum(d[near]) / np.sum(k[near]))  # every fitting gap's frames, not only the shortest
    return None


def pulses_in_log(rise: np.ndarray, period_us: float | None) -> float | None:
    """The fraction of the receiver's pulses the records carry (from their rising edges),
    while it was on (gaps longer than MAX_FILLED + 1 frames are the receiver off, not
    counted); None without a period."""
    if period_us is None or len(rise) < 2:
        return None
    k = np.round(np.diff(np.sort(np.asarray(rise, float))) / period_us)
    k = k[(k >= 1) & (k <= MAX_FILLED + 1)]
    return float(len(k) / k.sum()) if k.sum() else None


def logged_pulses(t_mcu_us, t_raw_us, steer_us, steer_t_us, mod: int):
    """The servo pulses the records carry, one each: (falling-edge times on the unwrapped
    MCU clock [us], widths [us]), in time order; empty without edge times (protocol v1)."""
    us = np.asarray(steer_us, float)
    t_fall = np.asarray(steer_t_us, np.int64)
    ok = (us > 0) & (t_fall != STEER_T_UNKNOWN)
    age = (np.asarray(t_raw_us, np.int64) - t_fall) % mod
    fall = np.asarray(t_mcu_us, np.int64) - age
    f, first = np.unique(fall[ok], return_index=True)
    return f, us[ok][first]


def _fill_lost_pulses(fall: np.ndarray, cmd: np.ndarray, period: float | None = None):
    """Pulses no record carries leave a hole in the staircase: the servo did receive them.
    Whose every sample was lost on the link, or that came between two samples (a receiver
    faster than the sample rate: each record holds only the latest pulse). A receiver
    sends at a steady period (``receiver_period_us``), so the missing edges are put back
    at that period and their commands interpolated between the neighbours (far closer
    to what the servo got than holding the last one through the hole, which would place
    every step late)."""
    if len(fall) < 3:
        return fall, cmd
    d = np.diff(fall)
    if period is None:
        period = float(np.median(d))
    if period <= 0:
        return fall, cmd
    n_missing = np.round(d / period).astype(np.int64) - 1
    holes = np.flatnonzero((n_missing >= 1) & (np.abs(d - (n_missing + 1) * period) < 0.25 * period)
                           & (n_missing <= MAX_FILLED))
    if not len(holes):
        return fall, cmd
    add_t, add_c = [], []
    for i in holes:
        k = np.arange(1, n_missing[i] + 1)
        tt = fall[i] + k * d[i] / (n_missing[i] + 1)
        add_t.append(np.round(tt).astype(np.int64))
        add_c.append(cmd[i] + (cmd[i + 1] - cmd[i]) * k / (n_missing[i] + 1))
    f2 = np.concatenate([fall] + add_t)
    c2 = np.concatenate([cmd] + add_c)
    o = np.argsort(f2, kind="stable")
    return f2[o], c2[o]


def mounting_from_gravity(g_sensor: np.ndarray) -> tuple[float, float]:
    """Roll and pitch (as stid.convert applies them) that turn gravity onto body z."""
    from scipy.optimize import least_squares

    res = least_squares(lambda a: (mount_rotation(a[0], a[1]) @ g_sensor)[:2], [0.0, 0.0])
    return float(res.x[0]), float(res.x[1])
