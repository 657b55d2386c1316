"""What the data still lack, in a driver's words.

Two kinds of lack:

- facts of the data: no stand-still yet (the gyro's zero is then unknown), no driving yet;
- what brings the parameters still short of their target there fastest. The information
  of the output-error fit (``stid.crlb.oe_terms``, with the fit's residual spectrum as
  noise, as ``stid plan --noise-from`` does) is worked out for the driving so far (the
  data's steer rms and bandwidth, for the seconds spent at each speed) and for one second
  of each thing a driver can add (more of the same, a second speed, faster steering,
  larger steer), all from ``stid.plan``'s random-steer spectrum; the one that reaches every
  target in the fewest seconds is named, with those seconds. The precision the fit shows
  now is the anchor: the plan only scales it by the information added.

A model-error allowance in the interval (``stid fit``'s exact-geometry widening) does not
shrink with more data: a parameter held up by it is told so, not sent driving.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from stid.errors import InputError
from stid.fit.steady_fit import LINEAR_AY  # (m/s^2: beyond about 0.4 g the tyres leave their linear range)

PLAN_S = 20.0  # seconds of each option's planned spectrum (information per second is taken from it)
MAX_S = 3600.0  # more than an hour of one thing is not a suggestion
# the loader takes the gyro zero from the stand-still less its last second before the car drives off
# (stid.convert.START_LOOKBACK_S): asked for 2 s, a trial's driver got a zero from 0.8 s
STILL_S = 3.0
NOISE_S = 60.0  # seconds of residual the noise spectrum is estimated from (the latest)
SPEED_BIN = 0.5  # m/s: the driving so far, weighed per speed
STAND_STILL = (f"stand still {STILL_S:g} s for the gyro zero (no stand-still in the data yet: the gyro's bias is "
               "not removed)")
NOTHING_TO_FIT = "drive: random steer (1-4 deg) at a steady speed; nothing to fit yet"
# what the data lack whatever the model (the rest is planned for the model watched)
FACTS_OF_THE_DATA = (STAND_STILL, NOTHING_TO_FIT)


def lacking(runs, res, model, params: list) -> list[str]:
    """Lines for the driver, most useful first. ``res``: the fit on the data so far (None
    when there is none); ``params``: its ParamState list (with the targets)."""
    out = []
    if any(r.meta.get("gyro_bias") is None and r.meta.get("format") == "mcap" for r in runs):
        out.append(STAND_STILL)
    if res is None:
        out.append(NOTHING_TO_FIT)
        return out
    short = [p for p in params if p.target is not None and not p.met]
    if not short:
        return out
    # a parameter the data do not determine yet (no interval) lacks excitation, whatever else holds its
    # interval: a steady circle was told "steer less (smaller angles)" for Iz beside "Iz: no interval"
    unseen = [p.name for p in short if p.percent is None and res.converged]
    if unseen:
        out.append(f"{', '.join(unseen)}: not determined by the data so far (no interval): drive random steer "
                   "(1-4 deg, up to 3-4 Hz), not only circles or steps, which hold one frequency")
    short = [p for p in short if p.percent is not None]
    out.extend(_stuck_on_model_error(res, short))
    short = [p for p in short if p.name not in _held_by_allowance(res, short, None)]
    if short:
        try:
            out.append(_best_addition(runs, res, model, short))
        except (InputError, np.linalg.LinAlgError, ValueError) as e:
            out.append(f"(what to add cannot be worked out on these data: {e})")
    return out


def _held_by_allowance(res, short, kind: str = "ci_allowance") -> set:
    """The parameters whose target the interval's allowance alone misses (``kind``: the geometry's,
    ``ci_allowance``, or a delay's, ``delay_allowance``; both when None)."""
    kinds = ("ci_allowance", "delay_allowance") if kind is None else (kind,)
    parts = [a for a in (getattr(res, k, None) for k in kinds) if a is not None]
    if not parts:
        return set()
    allow = np.sum(parts, axis=0)
    idx = {n: i for i, n in enumerate(res.names)}
    return {p.name for p in short if 100 * allow[idx[p.name]] / abs(p.value) >= p.target}


def _stuck_on_model_error(res, short) -> list[str]:
    out = []
    held = _held_by_allowance(res, short)
    if held:
        out.append(f"{', '.join(sorted(held))}: the interval holds the large-angle geometry the linear model leaves "
                   "out, which more data do not shrink: steer less (smaller angles), or accept the wider target")
    late = _held_by_allowance(res, short, "delay_allowance") - held
    if late:
        seen, chance = _delay_seen(res)
        out.append(f"{', '.join(sorted(late))}: the interval holds a delay between the steer and the outputs that the "
                   f"model leaves out{seen} (a servo's lag or dead time, a sensor's delay, or an accelerometer off the "
                   "CG, whose yaw-acceleration term reads as ay late or early); "
                   + ("if it is real, more data do not shrink it" if chance else "more data do not shrink it")
                   + ": watch a model with it (the diagnosis names which)")
    return out


def _delay_seen(res) -> tuple[str, bool]:
    """The delay the fit sees, its size against its standard error, and how often chance shows
    one that far out: the interval widens for a delay from 2 standard errors, so an exact model
    meets it by chance in about one fit of 20 (a plain-physics run in the suite: 0.07 ms at 2.6
    standard errors widened Iz's interval from 0.3% to 1.1%). A delay that is chance fades as the
    data grow; a real one stays. Returns the words and whether chance may have made it."""
    seen = res.extra.get("delay_seen_ms") if getattr(res, "extra", None) else None
    if not seen or not np.isfinite(seen[0]) or not seen[1] > 0:
        return "", True
    from scipy.special import ndtr

    z = abs(seen[0]) / seen[1]
    p = 2.0 * float(ndtr(-z))  # two-sided
    chance = (f"which chance gives in about 1 fit of {max(1, round(1 / p))}" if p > 1e-6 else
              "far beyond what chance gives")  # (a servo's lag: z in the tens or hundreds, p 0)
    return (f", the outputs {abs(seen[0]):.2g} ms {'late' if seen[0] > 0 else 'early'} at {z:.1f} standard errors, "
            f"{chance}", p > 1e-6)


def summary(runs, res) -> dict:
    """What the driving so far was: speed, steer rms, bandwidth, |ay|, and its spectrum."""
    from stid.fit.dataset import V_MOVING

    v = np.concatenate([r.vx[r.vx > V_MOVING] for r in runs]) if runs else np.zeros(0)
    steer = [np.asarray(p.steer)[p.keep] for p in res.predictions]
    ay = np.concatenate([np.asarray(p.y)[p.keep, 0] for p in res.predictions])
    fs = 1.0 / float(res.predictions[0].t[1] - res.predictions[0].t[0])
    f, P = _pooled_spectrum(steer, fs)
    cum = np.cumsum(P)
    bw = float(f[np.searchsorted(cum, 0.9 * cum[-1])]) if cum[-1] > 0 else 1.0
    above2 = float(cum[-1] - np.interp(2.0, f, cum)) / cum[-1] if cum[-1] > 0 else 0.0
    return {"speed": float(np.median(v)) if len(v) else 0.0,
            "speed_lo": float(np.percentile(v, 10)) if len(v) else 0.0,
            "speed_hi": float(np.percentile(v, 90)) if len(v) else 0.0,
            "amp": float(np.sqrt(np.mean(np.concatenate([s - s.mean() for s in steer]) ** 2))),
            "bw": min(max(bw, 0.5), 15.0), "above_2hz": above2,
            "ay95": float(np.percentile(np.abs(ay), 95)), "seconds": sum(len(s) for s in steer) / fs}


def _pooled_spectrum(pieces, fs, seg_s: float = 4.0):
    f0, acc = None, None
    for x in pieces:
        n = min(len(x), int(seg_s * fs))
        if n < 16:
            continue
        k = len(x) // n
        segs = (x[:k * n] - x.mean()).reshape(k, n) * np.hanning(n)
        P = np.mean(np.abs(np.fft.rfft(segs, axis=1)) ** 2, axis=0) * len(x)
        f = np.fft.rfftfreq(n, 1 / fs)
        if f0 is None:
            f0, acc = f, P
        else:
            acc = acc + np.interp(f0, f, P)
    if f0 is None:
        return np.array([0.0, 1.0]), np.zeros(2)
    return f0, acc


def _driven_terms(runs, model, params, names, noise, s) -> tuple:
    """(A, B) of the driving so far as the plan sees it: the data's random steer (its rms and
    bandwidth) for the seconds spent at each speed (bins of SPEED_BIN m/s). The additions are
    weighed by the same model, so the driving so far and an addition compare like with like
    (the plan's spectra are expected ones: a measured record's own DFT weighs the model-error
    term differently, and mixing the two made a second speed look twice as good as it is)."""
    from stid.fit.dataset import V_MOVING
    from stid.plan import Manoeuvre

    k = len(names)
    A, B = np.zeros((k, k)), np.zeros((k, k))
    seconds = {}
    for r in runs:
        v = r.vx[r.vx > V_MOVING]
        for b, n in zip(*np.unique(np.floor(v / SPEED_BIN).astype(int), return_counts=True)):
            seconds[b] = seconds.get(b, 0.0) + n / r.fs
    total = sum(seconds.values())
    for b, sec in seconds.items():
        if sec < 1.0:
            continue
        m = Manoeuvre((b + 0.5) * SPEED_BIN, max(s["amp"], math.radians(0.3)), s["bw"], PLAN_S)
        a, bb = _option_terms(model, params, names, noise, m)
        # the fitted seconds, shared out by the time spent at each speed
        A += a * sec / total * s["seconds"]
        B += bb * sec / total * s["seconds"]
    return A, B


def _option_terms(model, params, names, noise, m):
    """(A, B) per second of driving the planned manoeuvre ``m``."""
    from stid.crlb import oe_terms
    from stid.plan import ANALYSIS_FS, steer_dft

    f, U, n = steer_dft(replace(m, duration=PLAN_S))
    a, b, _ = oe_terms(model, params, names, f, U, n, ANALYSIS_FS, m.speed, noise, f_max=16.0)
    return a / PLAN_S, b / PLAN_S


def _variances(A, B):
    from stid.crlb import sandwich

    return np.diag(sandwich(A, B))


def _seconds_to_reach(A0, B0, a, b, idx, need) -> float:
    """Seconds of an addition (a, b per second) after which the variance of every parameter
    in ``idx`` has fallen by the factors ``need`` (<= 1); inf when MAX_S is not enough."""
    v0 = _variances(A0, B0)

    def ok(d):
        v = _variances(A0 + d * a, B0 + d * b)
        return all(v[i] <= need[j] * v0[i] for j, i in enumerate(idx))

    if not ok(MAX_S):
        return math.inf
    lo, hi = 0.0, MAX_S
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        if hi - lo < 1.0:
            break
    return hi


def _best_addition(runs, res, model, short) -> str:
    from stid.crlb import residual_model
    from stid.plan import Manoeuvre, check_grip

    params = res.all_params()
    names = list(res.names)
    noise = residual_model(_latest(res.predictions, NOISE_S))
    s = summary(runs, res)
    A0, B0 = _driven_terms(runs, model, params, names, noise, s)
    idx = [names.index(p.name) for p in short]
    need = [(p.target / p.percent) ** 2 for p in short]
    here = Manoeuvre(max(s["speed"], 1.0), max(s["amp"], math.radians(0.3)), s["bw"], PLAN_S)
    options = [("same", A0 / max(s["seconds"], 1e-9), B0 / max(s["seconds"], 1e-9), here)]
    v2 = 1.5 * here.speed
    for label, m in (("speed", replace(here, speed=v2)), ("speed", replace(here, speed=here.speed / 1.5)),
                     ("band", replace(here, bandwidth=min(max(1.5 * here.bandwidth, here.bandwidth + 1.0), 15.0))),
                     ("amp", replace(here, amp=1.5 * here.amp))):
        if m.speed < 1.5 or not _drivable(model, params, m, check_grip):
            continue
        a, b = _option_terms(model, params, names, noise, m)
        options.append((label, a, b, m))
    ranked = sorted(((_seconds_to_reach(A0, B0, a, b, idx, need), label, m) for label, a, b, m in options),
                    key=lambda x: x[0])
    which = ", ".join(p.name for p in short)
    best_s, label, m = ranked[0]
    if not math.isfinite(best_s):
        # (not "beyond this car": a trial's 0.7 Hz steering was told so for an Iz that 4 Hz steering at two
        # speeds reached in minutes; the plan weighs one step from the driving so far, as the data show it)
        return (f"{which}: by the plan, not even an hour more of any one step from this driving (the same, another "
                "speed, faster or larger steer) reaches the target; random steer up to 4 Hz at two speeds may, or "
                "the target is beyond this car and these sensors")
    return _words(label, m, s, best_s, which)


def _latest(predictions, seconds: float) -> list:
    """The last ``seconds`` of the fitted stretches: enough for the residual's spectrum (4 s
    Welch segments), which a whole long run only averages more finely at more cost."""
    from dataclasses import replace as copy_with

    out, left = [], seconds
    for p in reversed(predictions):
        n = len(p.t)
        take = min(n, int(round(left / float(p.t[1] - p.t[0]))))
        if take < n:
            sl = slice(n - take, n)
            p = copy_with(p, t=p.t[sl], steer=np.asarray(p.steer)[sl], y=p.y[sl], yhat=p.yhat[sl], keep=p.keep[sl])
        out.append(p)
        left -= take * float(p.t[1] - p.t[0])
        if left <= 0:
            break
    return out[::-1]


def _drivable(model, params, m, check_grip) -> bool:
    try:
        check_grip(model, params, m)
    except InputError:
        return False
    ay = float(abs(model.freqresp(params, np.array([0.05]), m.speed)[0, 0])) * m.amp * 2.0  # ~95% of |ay|
    return ay <= LINEAR_AY


def _words(label, m, s, seconds, which) -> str:
    took = f"about {_duration(seconds)} of it for {which}"
    if label == "same":
        return f"more of the same: about {_duration(seconds)} more driving like this for {which}"
    if label == "speed":
        span = (f"now {s['speed']:.1f} m/s only" if s["speed_hi"] - s["speed_lo"] < 0.3 * s["speed"]
                else f"now {s['speed_lo']:.1f}-{s['speed_hi']:.1f} m/s")
        return f"a second speed, about {m.speed:.1f} m/s ({span}): {took}"
    if label == "band":
        return (f"more steering above {s['bw']:.0f} Hz (so far {100 * s['above_2hz']:.0f}% of the steer's power is "
                f"above 2 Hz): quicker steering, up to {m.bandwidth:.0f} Hz, {took}")
    return (f"larger steer: |ay| < {s['ay95']:.1f} m/s² so far (95% of the time); "
            f"{math.degrees(m.amp):.1f} deg rms, {took}")


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"
