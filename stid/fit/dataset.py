"""Turn runs into what the fits use: stretches where the car moves (any speed
profile: the time-domain fit simulates with the measured speed), constant-speed
stretches for the methods that need one speed (frequency responses), both
prefiltered and decimated to ~200 Hz, and averaged steady-state points.

Samples lost on the link are never data: a run carries a ``valid`` mask, and
every decimated sample whose prefilter window reaches a lost sample is left out
of the cost (the simulation runs through with the input interpolated)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from stid import segments
from stid.errors import InputError
from stid.fit import filters
from stid.run import Run
from stid.sensor_chain import describe

TARGET_FS = 200.0  # the frequency-response methods' rate (their Welch settings were chosen at it)
# The time-domain fit's rate, one for every command (fit, compare, diagnose, report give the
# same numbers only on the same samples). The data are prefiltered at 20 Hz, but the model's
# first-order-hold input still has to follow the steer between samples: at 100 Hz that cost
# Iz -0.48% over 40 clean seeds (the 95% interval held the truth in 8% of them); at 200 Hz
# -0.02% on the same data. Half the speed is the price of the right answer.
FIT_FS = 200.0
MIN_STRETCH_S = 3.0
# Below this the single track is not the car's model (kinematic steering, slip angles
# from noise); standing still and reversing are left out too.
V_MOVING = 1.0  # m/s
# A lost raw sample spoils the prefiltered, decimated output near it: the grid holds an
# interpolated value there, which the filters smear. Measured on a 4 Hz band-limited
# signal with 17% of 20 ms frames lost (500 Hz, decimated to 250 Hz), the error left
# is 3.6% of the signal's rms within 10 ms of a loss, 0.7% at 10-20 ms, 0.36% at
# 20-30 ms: samples within 20 ms are left out of the cost (at 17% frame loss that
# leaves ~58% of the samples; a wider margin would leave too few to gain anything).
GAP_REACH_S = 0.02
# A gap this short spoils its neighbours by far less: the error linear interpolation leaves in
# it grows with the square of its length, and the prefilter spreads it over ~25 ms of measured
# samples. Such a gap's own samples are out of the cost, its neighbours stay in: a 200 Hz CSV
# missing one row in twenty had lost 55% of its samples to the margins above, and one in ten (or a
# slower channel's rows between its values) every sample, and the fit then ended in a traceback.
# Measured on exact single-track data with 180 single cells of ay and r missing at random: at
# 200 Hz (one row, 5 ms) the estimates moved by at most 0.55 of their interval's half-width; at
# 100 Hz (one row, 10 ms) Cr and Iz moved 1.4-1.6 half-widths, beyond their intervals: a 10 ms gap
# keeps its margins.
SHORT_GAP_S = 0.005
# Input and outputs are low-passed by the same zero-phase filter before fitting (an
# output-error prefilter: for a linear model, filtering both leaves the input-output
# relation unchanged). It removes what the model should not chase: the 50 Hz steps of
# the servo pulse train, engine vibration, noise above the vehicle's band.
PREFILTER_HZ = 20.0
OTHER_MEASURED = ("ax", "beta")  # optional logged channels a stretch carries beside its outputs


@dataclass
class Stretch:
    """A constant-speed piece of a run: inputs and measured outputs on a uniform grid."""

    name: str
    t: np.ndarray
    steer: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    vx_series: np.ndarray  # measured speed at every sample [m/s]: the model runs at it
    vx: float  # median speed [m/s], for labels and per-speed grouping
    valid: np.ndarray | None = None  # False where an output sample is not a measurement
    sensors: dict | None = None  # the sensor chain the outputs went through (stid.sensor_chain)
    measured: dict | None = None  # other logged channels on this grid (ax, beta): what a residual may follow
    # the gyro zero taken off r at load, from a stand-still of the same run (stid.convert.gyro_zero_from_still):
    # a gyro offset beyond it is at most the gyro's drift since (stid.analysis.kinematics); None: no zero taken
    gyro_zero: dict | None = None
    # a held command whose steps fall inside the outputs' sample periods (a ROS car's 50 Hz command
    # against a 30-60 Hz IMU): the steer and speed ``fine`` times as finely sampled (Run.steer_fine),
    # which the models are driven by; the outputs stay at the sensors' own instants
    steer_fine: np.ndarray | None = None
    vx_fine: np.ndarray | None = None
    fine: int = 1

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def simulation_input(self):
        """``(steer, dt, vx)`` the models are driven by: the fine steer where there is one (every
        ``fine``-th of a simulation's output samples is then this stretch's)."""
        if self.fine > 1:
            return self.steer_fine, self.dt / self.fine, self.vx_fine
        return self.steer, self.dt, self.vx_series

    def cut(self, a: int, b: int, step: int = 1, **changes) -> "Stretch":
        """Samples ``a:b:step`` of the stretch (``changes``: other fields to replace). Thinned
        (``step`` > 1) it keeps no fine input: it is for analyses that do not simulate."""
        from dataclasses import replace

        from stid.run import fine_piece

        sl = slice(a, b, step)
        n = len(self.t)
        fine = {"steer_fine": None, "vx_fine": None, "fine": 1}
        if self.fine > 1 and step == 1:
            fine = {"steer_fine": fine_piece(self.steer_fine, self.fine, a, b, n),
                    "vx_fine": fine_piece(self.vx_fine, self.fine, a, b, n), "fine": self.fine}
        return replace(self, **{"t": self.t[sl], "steer": self.steer[sl], "ay": self.ay[sl], "r": self.r[sl],
                                "vx_series": None if self.vx_series is None else self.vx_series[sl],
                                "valid": None if self.valid is None else self.valid[sl],
                                "measured": None if self.measured is None else
                                {k: x[sl] for k, x in self.measured.items()}, **fine, **changes})

    @property
    def y(self) -> np.ndarray:
        return np.column_stack([self.ay, self.r])


def _decimate(x: np.ndarray, q: int) -> np.ndarray:
    return filters.decimate(x, q) if q > 1 else x


def prefilter(x: np.ndarray, fs: float, f_hz: float = PREFILTER_HZ) -> np.ndarray:
    """4th-order Butterworth at f_hz, forward and backward (scipy.signal's butter and
    sosfiltfilt, as stid.fit.filters computes them)."""
    if not f_hz or f_hz >= 0.45 * fs:
        return x
    return filters.sosfiltfilt(filters.butter_lowpass_sos(4, f_hz, fs), x)


def decimation(fs: float, target_fs: float) -> int:
    """The decimation factor that brings ``fs`` nearest ``target_fs`` (as a ratio; none when
    fs is within 1.5x of it). Rounding fs / target_fs would flip at a ratio of 2.5 (500 Hz
    for 200) with the last bit of a median sample interval: the same car's log then fitted
    at 250 Hz or at 167 Hz, 1.5x the time, depending on how its clock's ticks rounded."""
    if fs <= 1.5 * target_fs:
        return 1
    x = fs / target_fs
    n = int(x)
    return n + 1 if x * x > n * (n + 1) else n


def filtered(run: Run, target_fs: float = TARGET_FS, names=("steer", "ay", "r", "vx")):
    """Prefilter and decimate whole signals of a run (so stretches cut from them carry
    no filter edge transients): (decimation factor, dict of arrays, time). The dict
    holds ``valid`` too: False where the prefilter reaches a lost sample. A run with a
    fine steer (Run.steer_fine) is neither: its outputs and its input are on different
    grids, where one discrete filter is not the same filter on both."""
    fs = run.fs
    q = 1 if run.fine > 1 else decimation(fs, target_fs)
    # every signal at once, one column each: the same numbers as one by one (each column is
    # filtered on its own); one call into scipy.signal's compiled filter where stid live uses it
    cols = np.column_stack([getattr(run, n) if hasattr(run, n) and getattr(run, n) is not None else run.extra[n]
                            for n in names])
    smooth = cols if run.fine > 1 else prefilter(cols, fs)
    out = {n: _decimate(np.ascontiguousarray(smooth[:, i]), q) for i, n in enumerate(names)}
    m = min(len(v) for v in out.values())
    out = {k: v[:m] for k, v in out.items()}
    valid = np.ones(len(run.t), bool) if run.valid is None else np.asarray(run.valid, bool)
    if not valid.all() and smooth is not cols:  # (unfiltered, a placeholder spoils its own sample only)
        reach = int(np.ceil(GAP_REACH_S * fs))
        short = int(np.floor(SHORT_GAP_S * fs + 1e-9))
        lost = ~valid
        spoils = np.zeros(len(lost))
        for a, b in segments.runs_of(lost, short + 1):  # (the gaps longer than short)
            spoils[a:b] = 1.0
        valid = (segments.uniform_filter1d(spoils, 2 * reach + 1) == 0.0) & ~lost
    out["valid"] = valid[::q][:m]
    return q, out, run.t[::q][:m]


class Stretches(list):
    """The stretches of some runs, with notes on what was left out and why."""

    notes: list

    def __init__(self, items=(), notes=None):
        super().__init__(items)
        self.notes = list(notes or [])


_BUILT: dict = {}  # (the runs, the arguments) -> their Stretches: a command asks several times


def held_out_stretches(runs) -> Stretches:
    """The stretches of runs held out to judge a fit on (``--validate``): when they hold none,
    the message says these are the held-out runs, not the ones fitted to."""
    try:
        return dynamic_stretches(runs)
    except InputError as e:
        raise InputError(f"the held-out run(s) given to --validate cannot judge the fit: {e}") from None


def dynamic_stretches(runs: list[Run], min_s: float = MIN_STRETCH_S, target_fs: float | None = None,
                      trim_s: float = 0.5, constant_speed: bool = False, method: str = "") -> Stretches:
    """Stretches of every run for the dynamic fits (built once for the same runs and
    arguments: ``stid fit`` fits and then judges on them; treat them as read-only).

    By default every stretch where the car moves forward faster than ``V_MOVING`` for
    at least ``min_s`` (the time-domain fit follows the measured speed). With
    ``constant_speed`` only stretches whose speed stays within +-5% of their own: the
    frequency-response methods (named by ``method`` in messages) need one speed.
    ``target_fs``: default FIT_FS, or TARGET_FS with ``constant_speed``.
    """
    runs = tuple(runs)
    key = (tuple(id(r) for r in runs), min_s, target_fs, trim_s, constant_speed, method)
    hit = _BUILT.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], runs)):
        return hit[1]
    built = _dynamic_stretches(runs, min_s, target_fs, trim_s, constant_speed, method)
    if len(_BUILT) >= 4:
        _BUILT.pop(next(iter(_BUILT)))
    _BUILT[key] = (runs, built)  # the runs are held, so their ids cannot be reused while cached
    return built


def _dynamic_stretches(runs, min_s, target_fs, trim_s, constant_speed, method) -> Stretches:
    if target_fs is None:
        target_fs = TARGET_FS if constant_speed else FIT_FS
    out = []
    reasons = []
    notes = []
    for run in runs:
        fs = run.fs
        if constant_speed:
            found = segments.constant_speed(run.vx, fs, min_s=min_s + 2 * trim_s)
            what = "at constant speed"
        else:
            found = segments.runs_of(run.vx > V_MOVING, int((min_s + 2 * trim_s) * fs))
            what = f"moving faster than {V_MOVING:g} m/s"
            left = float(np.sum(run.vx <= V_MOVING)) / fs
            back = float(np.sum(run.vx < -0.05)) / fs
            if left > 0.5:
                notes.append(f"{run.name}: {left:.1f} s standing still or slower than {V_MOVING:g} m/s"
                             + (f" ({back:.1f} s of it reversing)" if back > 0.1 else "")
                             + " left out of the dynamic fit")
        if not found:
            reasons.append(f"{run.name}: no stretch of at least {min_s + 2 * trim_s:.0f} s {what}")
            continue
        other = tuple(n for n in OTHER_MEASURED if getattr(run, n) is not None)
        q, sig, t = filtered(run, target_fs, names=("steer", "ay", "r", "vx") + other)
        for k, (a, b) in enumerate(found):
            a = (a + int(trim_s * fs)) // q
            b = min((b - int(trim_s * fs)) // q, len(t))
            sl = slice(a, b)
            valid = sig["valid"][sl]
            vx_series = np.maximum(sig["vx"][sl], 0.5 * V_MOVING)
            fine = {}
            if run.fine > 1:  # (q is 1: the samples are the run's)
                from stid.run import fine_piece

                m = run.fine
                t_fine = t[a] + np.arange((len(t[sl]) - 1) * m + 1) * (run.dt / m)
                fine = {"steer_fine": fine_piece(run.steer_fine, m, a, b, len(run.t)), "fine": m,
                        "vx_fine": np.interp(t_fine, t[sl], vx_series)}
            out.append(Stretch(name=run.name if len(found) == 1 else f"{run.name}[{k + 1}]", t=t[sl],
                               steer=sig["steer"][sl], ay=sig["ay"][sl], r=sig["r"][sl],
                               vx_series=vx_series, **fine,
                               vx=float(np.median(run.vx[a * q:b * q])),
                               valid=None if valid.all() else valid,
                               sensors=run.meta.get("sensor_chain"),
                               measured={n: sig[n][sl] for n in other} or None,
                               gyro_zero=run.meta.get("gyro_zero")))
    if not out:
        if constant_speed:
            raise InputError(f"the {method or 'frequency-response'} method needs stretches at one constant "
                             "speed, and no run has one (" + "; ".join(reasons) + "). Use --method time, "
                             "which follows the measured speed, or drive at constant speed")
        raise InputError("no run has a stretch where the car moves to fit the dynamics to ("
                         + "; ".join(reasons) + "). Drive random steer or a lane change, "
                         "or fit steady-state circles with 'stid fit --method steady'")
    # a stretch of constant steer (a steady circle) holds no dynamic information, only model error
    moving = [s for s in out if np.std(s.steer) >= np.radians(0.1)]
    if not moving:
        raise InputError("the steer is (nearly) constant in every stretch: it does not excite "
                         "the dynamics, so no dynamic parameter can be identified. Drive random steer "
                         "(1-4 deg) or a lane change")
    if len(moving) < len(out):
        notes.append(f"{len(out) - len(moving)} stretch(es) with (nearly) constant steer left out of the "
                     "dynamic fit (no dynamic information)")
    chains = {describe(s.sensors) for s in moving}
    notes.extend(sorted(chains))
    lost = sum(int((~s.valid).sum()) for s in moving if s.valid is not None)
    total = sum(len(s.t) for s in moving)
    usable_s = sum(int(len(s.t) if s.valid is None else s.valid.sum()) * s.dt for s in moving)
    if usable_s < MIN_STRETCH_S:
        # (a fit on none would end nowhere: every residual out of the cost, nan fit percents)
        raise InputError(f"of {sum(len(s.t) * s.dt for s in moving):.1f} s of driving with steering, {usable_s:.2f} s "
                         f"are measurements the fit can use, under the {MIN_STRETCH_S:g} s it needs: the rest "
                         f"lack a value (lost on the link or by a driver, or a row a file lacks or holds no number "
                         f"in) or lie within {1e3 * GAP_REACH_S:.0f} ms of a gap longer than {1e3 * SHORT_GAP_S:.0f} ms "
                         "of them. Record the outputs in every row, or at least without long gaps")
    if lost:
        notes.append(f"{100 * lost / total:.1f}% of the fitted samples are out of the cost: not measured (lost on "
                     f"the link or by a driver, or a row a file lacks or holds no number in) or within {1e3 * GAP_REACH_S:.0f} ms "
                     f"of a gap of them longer than {1e3 * SHORT_GAP_S:.0f} ms, where the prefilter smears it")
    return Stretches(moving, notes)


def check_excitation(stretches: list[Stretch]) -> list[str]:
    """Warnings when the steering does not excite the dynamics."""
    # (stretches without any steering were already refused by dynamic_stretches)
    warns = []
    for s in stretches:
        if np.std(s.steer) < np.radians(0.3):
            warns.append(f"{s.name}: weak excitation (steer rms {np.degrees(np.std(s.steer)):.2f} deg)")
    return warns


@dataclass
class SteadyPoints:
    steer: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    vx: np.ndarray
    beta: np.ndarray | None


def steady_points(runs: list[Run], window_s: float = 0.5) -> SteadyPoints:
    """Averages over windows of quasi-steady cornering (constant r, vx and steer)."""
    cols = {k: [] for k in ("steer", "ay", "r", "vx", "beta")}
    have_beta = all(r.beta is not None for r in runs)
    for run in runs:
        fs = run.fs
        mask = segments.steady_state(run.steer, run.ay, run.r, run.vx, fs, window_s=1.0)
        w = max(2, int(window_s * fs))
        for a, b in segments.runs_of(mask, w):
            for i in range(a, b - w + 1, w):
                sl = slice(i, i + w)
                cols["steer"].append(np.mean(run.steer[sl]))
                cols["ay"].append(np.mean(run.ay[sl]))
                cols["r"].append(np.mean(run.r[sl]))
                cols["vx"].append(np.mean(run.vx[sl]))
                if have_beta:
                    cols["beta"].append(np.mean(run.beta[sl]))
    pts = {k: np.asarray(v) for k, v in cols.items()}
    return SteadyPoints(pts["steer"], pts["ay"], pts["r"], pts["vx"], pts["beta"] if have_beta else None)
