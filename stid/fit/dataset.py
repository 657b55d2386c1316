"""Turn runs into what the fits use: constant-speed stretches for the dynamic
fits (start-up trimmed, decimated to ~200 Hz) and averaged steady-state points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from stid import segments
from stid.errors import InputError
from stid.run import Run

TARGET_FS = 200.0
MIN_STRETCH_S = 3.0
# Input and outputs are low-passed by the same zero-phase filter before fitting (an
# output-error prefilter: for a linear model, filtering both leaves the input-output
# relation unchanged). It removes what the model should not chase: the 50 Hz steps of
# the servo pulse train, engine vibration, noise above the vehicle's band.
PREFILTER_HZ = 20.0


@dataclass
class Stretch:
    """A constant-speed piece of a run: inputs and measured outputs on a uniform grid."""

    name: str
    t: np.ndarray
    steer: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    vx_series: np.ndarray
    vx: float

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def y(self) -> np.ndarray:
        return np.column_stack([self.ay, self.r])


def _decimate(x: np.ndarray, q: int) -> np.ndarray:
    return signal.decimate(x, q, ftype="fir", zero_phase=True) if q > 1 else x


def prefilter(x: np.ndarray, fs: float, f_hz: float = PREFILTER_HZ) -> np.ndarray:
    if not f_hz or f_hz >= 0.45 * fs:
        return x
    sos = signal.butter(4, f_hz, fs=fs, output="sos")
    return signal.sosfiltfilt(sos, x)


def filtered(run: Run, target_fs: float = TARGET_FS, names=("steer", "ay", "r", "vx")):
    """Prefilter and decimate whole signals of a run (so stretches cut from them carry
    no filter edge transients): (decimation factor, dict of arrays, time)."""
    fs = run.fs
    q = max(1, int(round(fs / target_fs))) if fs > 1.5 * target_fs else 1
    out = {}
    for n in names:
        x = getattr(run, n) if hasattr(run, n) and getattr(run, n) is not None else run.extra[n]
        out[n] = _decimate(prefilter(x, fs), q)
    m = min(len(v) for v in out.values())
    return q, {k: v[:m] for k, v in out.items()}, run.t[::q][:m]


def dynamic_stretches(runs: list[Run], min_s: float = MIN_STRETCH_S, target_fs: float = TARGET_FS,
                      trim_s: float = 0.5) -> list[Stretch]:
    """Constant-speed stretches of every run, for the frequency- and time-domain fits."""
    out = []
    reasons = []
    for run in runs:
        fs = run.fs
        found = segments.constant_speed(run.vx, fs, min_s=min_s + 2 * trim_s)
        if not found:
            reasons.append(f"{run.name}: no stretch of at least {min_s + 2 * trim_s:.0f} s at constant speed")
            continue
        q, sig, t = filtered(run, target_fs)
        for k, (a, b) in enumerate(found):
            a = (a + int(trim_s * fs)) // q
            b = min((b - int(trim_s * fs)) // q, len(t))
            sl = slice(a, b)
            out.append(Stretch(name=run.name if len(found) == 1 else f"{run.name}[{k + 1}]", t=t[sl],
                               steer=sig["steer"][sl], ay=sig["ay"][sl], r=sig["r"][sl], vx_series=sig["vx"][sl],
                               vx=float(np.median(run.vx[a * q:b * q]))))
    if not out:
        raise InputError("no run has a constant-speed stretch to fit the dynamics to ("
                         + "; ".join(reasons) + "). Drive random steer or a lane change at constant "
                         "speed, or use --method steady for steady-state circles")
    # a stretch of constant steer (a steady circle) holds no dynamic information, only model error
    moving = [s for s in out if np.std(s.steer) >= np.radians(0.1)]
    if not moving:
        raise InputError("the steer is (nearly) constant in every constant-speed stretch: it does not excite "
                         "the dynamics, so no dynamic parameter can be identified. Drive random steer "
                         "(1-4 deg) or a lane change")
    return moving


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
