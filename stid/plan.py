"""``stid plan``: design the test before driving.

For a model, parameter values (defaults, the vehicle file's [params], or a
previous fit) and a set of proposed manoeuvres, the plan predicts the standard
deviation each parameter will have when ``stid fit`` (an output-error fit, one
weight per output: stid.crlb.oe_covariance; for white noise that is the
Cramér-Rao bound) is run on them. The steer of each manoeuvre enters through its
expected spectrum (random steer: band-limited white noise of the given rms and
bandwidth, as drivers and steering robots produce), the noise through its spectrum.

What "noise" is decides how honest the prediction is:

- the sensors' datasheet noise densities, or the stand-still part of a run: sensor
  noise alone. That assumes the model is exactly the car, and predicts too little:
  on the simulated car the observed spread is several times that (``make bench``);
- the *residual* spectrum of a fit to a run that drove (``noise_from_runs``): model
  error + noise, what the fit actually meets. On the simulated car this predicts the
  Monte-Carlo spread within the bench's goal (0.7-1.4x; the figures are in the
  README's "Performance (`make bench`)" and docs/bench.md). It is a property of that car, that model and
  that kind of driving: a plan from it is as good as the run is typical.

The report says which noise it used.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal

from stid.crlb import fisher_spectrum, noise_psd_from_still, oe_terms, residual_model, sandwich
from stid.errors import InputError
from stid.fit.dataset import PREFILTER_HZ
from stid.models.model import Model

G = 9.81
ANALYSIS_FS = 200.0
MAX_BW_HZ = PREFILTER_HZ  # the fits low-pass everything at 20 Hz: steer above it is lost
MAX_AMP = math.radians(15.0)  # rms steer: an RC car's wheels turn about 25-30 deg at full lock
# datasheet noise densities (one-sided): ADXL335 x/y 150 ug/sqrt(Hz), LISY300AL 0.05 deg/s/sqrt(Hz) (assumed)
ADXL335_NOISE = 150e-6 * G
LISY300AL_NOISE = math.radians(0.05)


@dataclass
class Manoeuvre:
    speed: float  # m/s
    amp: float  # rad, rms road-wheel steer
    bandwidth: float  # Hz
    duration: float  # s

    def label(self) -> str:
        return (f"random steer {math.degrees(self.amp):.1f} deg rms up to {self.bandwidth:g} Hz for "
                f"{self.duration:g} s at {self.speed:g} m/s")


def parse_manoeuvre(text: str) -> Manoeuvre:
    """``speed=5,amp=2deg,bw=4,dur=60`` (amp in deg or rad; defaults amp 2 deg, bw 4 Hz, dur 40 s)."""
    kv = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        if "=" not in part:
            raise InputError(f"manoeuvre {text!r}: write key=value pairs, e.g. speed=5,amp=2deg,bw=4,dur=60")
        k, v = part.split("=", 1)
        kv[k.strip()] = v.strip()
    unknown = set(kv) - {"speed", "amp", "bw", "dur"}
    if unknown:
        raise InputError(f"manoeuvre {text!r}: unknown key(s) {', '.join(sorted(unknown))}; "
                         "use speed, amp, bw, dur")
    if "speed" not in kv:
        raise InputError(f"manoeuvre {text!r} needs speed=... [m/s]")

    def num(s, what):
        m = re.fullmatch(r"([-+0-9.eE]+)\s*(deg|rad|hz|Hz|s|m/s)?", s)
        if not m:
            raise InputError(f"manoeuvre {text!r}: {what} {s!r} is not a number")
        return float(m.group(1)), m.group(2)

    speed, _ = num(kv["speed"], "speed")
    amp, unit = num(kv.get("amp", "2deg"), "amp")
    if unit == "deg" or (unit is None and amp > 0.5):
        amp = math.radians(amp)
    bw, _ = num(kv.get("bw", "4"), "bw")
    dur, _ = num(kv.get("dur", "40"), "dur")
    if not (speed > 0.5 and amp > 0 and bw > 0 and dur > 2):  # (nan fails every one)
        raise InputError(f"manoeuvre {text!r}: speed > 0.5 m/s, amp > 0, bw > 0 and dur > 2 s are needed")
    if bw >= MAX_BW_HZ:
        raise InputError(f"manoeuvre {text!r}: bw {bw:g} Hz is beyond what the fits use (they low-pass the data "
                         f"at {MAX_BW_HZ:g} Hz); random steer below that (4-8 Hz is typical)")
    if amp > MAX_AMP:
        raise InputError(f"manoeuvre {text!r}: amp {math.degrees(amp):.0f} deg rms is beyond the steering's travel "
                         f"and the linear tyre range; at most {math.degrees(MAX_AMP):.0f} deg rms (1-4 deg is "
                         "typical)")
    return Manoeuvre(speed, amp, bw, dur)


def steer_dft(m: Manoeuvre, fs: float = ANALYSIS_FS):
    """Expected |U_k| of the manoeuvre's steer (deterministic: the spectrum's square root)."""
    n = int(m.duration * fs)
    f = np.fft.rfftfreq(n, 1 / fs)
    b, a = signal.butter(6, m.bandwidth, fs=fs)
    _, h = signal.freqz(b, a, worN=f, fs=fs)
    shape = np.abs(h) ** 2 * np.abs(h) ** 2  # sosfiltfilt: the filter applied twice
    # scale so the signal's variance is amp^2: sum |U_k|^2 (both sides) = n^2 var
    p = shape / (2 * np.sum(shape[1:]))
    return f, np.sqrt(p * n * n) * m.amp, n


MAX_AY_RMS = G  # m/s^2: 1 g rms of lateral acceleration is beyond any tyre's grip


def check_grip(model: Model, params: dict, m: Manoeuvre) -> None:
    """A manoeuvre the car cannot drive: its steer at its speed asks for more lateral
    acceleration than any tyre gives (the linear model would happily plan it)."""
    ay = float(abs(model.freqresp(params, np.array([0.05]), m.speed)[0, 0])) * m.amp
    if not ay <= MAX_AY_RMS:
        raise InputError(f"manoeuvre {m.label()}: at {m.speed:g} m/s that steer asks for {ay / G:.1f} g of lateral "
                         "acceleration (rms), more than any tyre gives; drive slower or steer less (the linear "
                         "model holds to about 0.4 g)")


def datasheet_noise(fs: float = ANALYSIS_FS, sample_rate: float = 500.0, vehicle=None) -> dict:
    """One-sided noise PSD of ay and r from the datasheets: the sensors' noise densities
    through their output filters, plus 12-bit ADC quantisation at the firmware's rate."""
    sensors = getattr(vehicle, "sensors", {}) or {}
    bw_a = float(sensors.get("accel_bandwidth_hz", 50.0)) or np.inf
    bw_g = float(sensors.get("gyro_bandwidth_hz", 88.0)) or np.inf
    f = np.linspace(0, fs / 2, 512)
    lsb_a = 3.3 / 4095 / 0.33 * G  # m/s^2 per count (ratiometric, 3.3 V)
    lsb_g = math.radians(3.3 / 4095 / 3.3e-3)  # rad/s per count
    q = lambda lsb: lsb ** 2 / 12 / (sample_rate / 2)  # noqa: E731
    return {"ay": (f, ADXL335_NOISE ** 2 / (1 + (f / bw_a) ** 2) + q(lsb_a)),
            "r": (f, LISY300AL_NOISE ** 2 / (1 + (f / bw_g) ** 2) + q(lsb_g))}


ESTIMATORS = ("output-error", "efficient")


def predict(model: Model, params: dict, manoeuvres: list[Manoeuvre], noise: dict, names=None,
            estimator: str = "output-error") -> dict:
    """Predicted covariance of the parameters. ``estimator``: ``"output-error"`` (what
    ``stid fit`` ships: the sandwich for the noise's colour) or ``"efficient"`` (the
    Cramér-Rao bound, what a fit that whitens the noise would reach). The two agree for
    white noise; ``info`` is the Fisher information either way (information adds)."""
    if estimator not in ESTIMATORS:
        raise InputError(f"unknown estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")
    names = names or [n for n in model.param_names]
    k = len(names)
    info, A, B = np.zeros((k, k)), np.zeros((k, k)), np.zeros((k, k))
    for m in manoeuvres:
        f, U, n = steer_dft(m)
        kw = dict(f_max=min(0.8 * PREFILTER_HZ, 0.45 * ANALYSIS_FS))
        if estimator == "output-error":
            a, b, i = oe_terms(model, params, names, f, U, n, ANALYSIS_FS, m.speed, noise, **kw)
            A += a
            B += b
            info += i
        else:
            info += fisher_spectrum(model, params, names, f, U, n, ANALYSIS_FS, m.speed, noise, **kw)
    # a parameter the steer's response carries no information about (a constant offset acts at
    # 0 Hz, which the plan's spectra leave out) has no predicted sd: nan, not the 0 a
    # pseudo-inverse gives it; the others are predicted without it
    d = np.diag(info)
    seen = d > 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
    cov = np.full((k, k), np.nan)
    ix = np.ix_(seen, seen)
    cov[ix] = sandwich(A[ix], B[ix]) if estimator == "output-error" else np.linalg.pinv(info[ix])
    sd = np.sqrt(np.maximum(np.diag(cov), 0))
    # A combination of parameters the steer's response does not move (a steering compliance against
    # a softer front axle; a stiffness growing with vx^2 at one speed) has no sd: the pseudo-inverse
    # gives the parameters in it a finite, tiny one (a trial user was promised c_steer to 0.6%, and Cf
    # to 1e-10 N/rad). Each parameter with a part in such a combination is said to have none.
    tied = _undetermined(info[ix])
    for i, j in enumerate(np.flatnonzero(seen)):
        if tied[i]:
            sd[j] = np.nan
            cov[j, :] = cov[:, j] = np.nan
    seen = seen & np.isfinite(sd)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    return {"names": names, "sd": dict(zip(names, sd)), "cov": cov, "corr": np.nan_to_num(corr),
            "info": info, "estimator": estimator}


NULL_SHARE = 1e-6  # an eigenvalue of the information's correlation form this far below the largest: none


def _undetermined(info: np.ndarray) -> np.ndarray:
    """Which parameters have a part in a combination the information holds none of (bool per row)."""
    if not len(info):
        return np.zeros(0, bool)
    scale = np.sqrt(np.diag(info))
    w, V = np.linalg.eigh(info / np.outer(scale, scale))
    null = w < NULL_SHARE * max(float(w.max()), 1e-300)
    return np.any(np.abs(V[:, null]) > 1e-3, axis=1) if null.any() else np.zeros(len(info), bool)


def noise_from_fit(result) -> dict:
    """A time-domain fit's residual as the plan's noise: its part incoherent with the steer
    (sensor noise and more) as noise, and its linear response to the steer as model error
    (stid.crlb.residual_model)."""
    return residual_model(result.predictions)


def noise_from_runs(runs, vehicle, model_name: str = "bicycle", label: str = "the run",
                    vehicle_path: str = "V.toml") -> tuple:
    """Noise for the plan from runs that drove: ``(noise, source, params, warnings)``.

    The runs are fitted with ``model_name`` as ``stid fit`` would, and the residual
    spectrum (model error + sensor noise) is the noise: the spread a fit shows on data
    from this car is set by what the model misses as much as by the sensors. Runs that
    never drive fall back to their stand-still (sensor noise alone), which says so.
    ``params`` are the fitted values (None on the fallback); ``warnings``: where the fit
    is far below the runs' noise floor (missing_effect_warning; ``vehicle_path`` for its command)."""
    from stid.fit.fitting import fit

    still = noise_psd_from_still(runs)
    try:
        res = fit(runs, vehicle, model_name, "time", intervals="noise")
    except InputError:
        res = None
    if res is None or not res.predictions:
        if still is None:
            raise InputError(f"{label} neither stands still nor drives with steering: no noise level in it")
        return still, f"the stand-still of {label} (sensor noise only: the model is assumed exact, which " \
                      "predicts too little spread; give a run with steering to include model error)", None, []
    noise = noise_from_fit(res)
    source = f"the residuals of a {model_name} fit to {label} (model error + sensor noise" + (
        "" if res.converged else "; that fit did not converge, so they also hold the solver's failure")
    source += "; the part that follows the steer: {}".format(
        ", ".join(f"{o} {100 * x:.0f}%" for o, x in noise["follows_steer"].items()))
    if still is not None:
        band = lambda fp: float(np.mean(np.interp(np.linspace(0.5, 8, 32), *fp)))  # noqa: E731
        ratio = {o: math.sqrt(band(noise[o]) / band(still[o])) for o in ("ay", "r")}
        source += "; the rest is {} the stand-still's sensor noise in 0.5-8 Hz".format(
            ", ".join(f"{o} {x:.1f}x" for o, x in ratio.items()))
    return noise, source + ")", res.all_params(), missing_effect_warning(res, runs, [label], vehicle_path)


def missing_effect_warning(res, runs, paths: list, vehicle_path: str) -> list[str]:
    """A warning where the fit ``res`` to ``runs`` (from the files ``paths``) is far below their noise
    floor (stid.analysis.noise_floor.below_floor), empty otherwise. The plan assumes the model is the car: a model that
    misses an effect bends its fitted values to make up for it (a trial's car with a 40 ms servo
    lag, fitted and planned as a bicycle: Iz +90%, planned to 2.1%), and nothing else in a plan
    says so."""
    from stid.analysis.noise_floor import runs_below_floor

    short = runs_below_floor(res, runs)
    if not short:
        return []
    import shlex

    gap = ", ".join(f"{o} {g:.1f} points" for o, g in short.items())
    label = ", ".join(map(str, paths))
    if not res.converged:
        return [f"the {res.model} fit to {label} did not converge, and is far below the noise floor there ({gap}): "
                "the values assumed are where its solver stopped"]
    return [f"{res.model} fits {label} far below its noise floor ({gap}): it misses an effect, which bends the "
            "values assumed here (and the spread planned around them) by more than they show. Find it with "
            f"'{shlex.join(['stid', 'diagnose', *map(str, paths), '--vehicle', str(vehicle_path), '--model', res.model])}' "
            "and plan with that model"]


def suggestions(model, params, manoeuvres, noise, targets: dict) -> list[str]:
    """What to add to reach each target (relative sd): more time, wider bandwidth, or a second speed."""
    base = predict(model, params, manoeuvres, noise)
    out = []
    for name, target in targets.items():
        if name not in base["sd"]:
            raise InputError(f"--target {name}: the model {model.name} has no parameter {name}; its parameters: "
                             f"{', '.join(base['names'])}")
        if not np.isfinite(base["sd"][name]):
            out.append(f"{name}: no target can be planned for it (no sd predicted: see the note above)")
            continue
        if params[name] == 0:
            out.append(f"{name}: its assumed value is 0, so a target in percent of it means nothing; give the "
                       "value you expect in the vehicle file's [params]")
            continue
        rel = base["sd"][name] / abs(params[name])
        if rel <= target:
            out.append(f"{name}: sd {100 * rel:.2g}% predicted, within the {100 * target:g}% target")
            continue
        ref = manoeuvres[0]
        options = [
            ("the same manoeuvre again", replace(ref)),
            ("a second speed (1.5x)", replace(ref, speed=ref.speed * 1.5)),
            ("random steer up to 1.5x the bandwidth", replace(ref, bandwidth=ref.bandwidth * 1.5)),
            ("more steer (1.5x rms)", replace(ref, amp=ref.amp * 1.5)),
        ]
        best = None
        for label, extra in options:
            try:
                check_grip(model, params, extra)  # (1.5x the speed or the steer may ask too much)
            except InputError:
                continue
            sd = predict(model, params, manoeuvres + [extra], noise)["sd"][name] / abs(params[name])
            gain = (1 / sd ** 2 - 1 / rel ** 2) / extra.duration  # information per second of driving
            if best is None or gain > best[0]:
                best = (gain, label, extra, sd)
        if best is None:
            out.append(f"{name}: none of the additions it weighs can be driven (too much lateral acceleration)")
            continue
        gain, label, extra, sd = best
        extra, sd = _long_enough(model, params, manoeuvres, noise, name, extra, rel, target, gain)
        reach = (f"then sd {100 * sd:.2g}%" if sd <= target else
                 f"which still leaves sd {100 * sd:.2g}%: the target is beyond what {MAX_PLAN_S / 3600:g} h of "
                 "this manoeuvre adds")
        out.append(f"{name} sd {100 * target:g}% needs {extra.label()} in addition ({reach}; now {100 * rel:.2g}%; "
                   "best of: more time, another speed, wider bandwidth, more steer)")
    names = base["names"]
    effects = {e.name for e in model.effects}
    if {"actuator_lag", "tyre_relaxation"} <= effects and len({m.speed for m in manoeuvres}) == 1:
        i, j = names.index("tau_steer"), names.index("sigma_f")
        out.append(f"servo lag and relaxation are {abs(base['corr'][i, j]):.2f} correlated at one speed: to "
                   "separate them add a second speed (relaxation lag scales with 1/speed, servo lag does not)")
    return out


MAX_PLAN_S = 4 * 3600.0  # seconds of one manoeuvre a plan suggests at most (a day of track time)


def _long_enough(model, params, manoeuvres, noise, name, extra, rel, target, gain, tries: int = 8):
    """``extra`` lengthened (in 10 s steps, to MAX_PLAN_S at most) until the plan predicts
    ``target`` for ``name``, and the sd it then predicts. The information a manoeuvre adds grows
    with its duration, but a parameter correlated with others gains less than its share of it:
    the first guess (information adds, at ``gain`` per second) fell short by up to a quarter, so
    each guess is checked and scaled by the information still missing."""
    need = (1 / target ** 2 - 1 / rel ** 2) / max(gain, 1e-300)
    sd = rel
    for _ in range(tries):
        extra = replace(extra, duration=float(min(np.ceil(need / 10) * 10, MAX_PLAN_S)))
        sd = predict(model, params, manoeuvres + [extra], noise)["sd"][name] / abs(params[name])
        added = 1 / sd ** 2 - 1 / rel ** 2
        if sd <= target or added <= 0 or extra.duration >= MAX_PLAN_S:
            break
        need = extra.duration * (1 / target ** 2 - 1 / rel ** 2) / added
    return extra, sd


def plan_report(model, params, manoeuvres, noise, targets, noise_source: str,
                params_source: str = "the model's defaults and the vehicle file's [params]",
                warnings=()) -> tuple[str, dict]:
    """The plan as text and as JSON. ``warnings``: said before the numbers (missing_effect_warning)."""
    pred = predict(model, params, manoeuvres, noise)
    lines = [f"plan for {model.name} (cornering stiffness per axle, N/rad; noise from {noise_source})",
             f"  parameter values assumed (not estimates): {params_source}"]
    lines += [f"  warning: {w}" for w in warnings]
    for m in manoeuvres:
        lines.append(f"  drive: {m.label()}")
    lines.append(f"  {'parameter':<14}{'value':>12}{'predicted sd':>15} {'':>11}  unit")
    stuck, unseen = [], []
    for n in pred["names"]:
        v = params[n]
        sd = pred["sd"][n]
        if not np.isfinite(sd):
            unseen.append(n)
            lines.append(f"  {n:<14}{v:>12.5g}{'-':>15} {'':>11}  {model.param(n).unit}")
            continue
        pct = 100 * sd / abs(v) if v else 0.0
        rel = (f"({pct:.1f}%)" if pct >= 0.1 else f"({pct:.2g}%)") if v else ""  # (a bare 0.0% read as exact)
        lines.append(f"  {n:<14}{v:>12.5g}{sd:>15.4g} {rel:>11}  {model.param(n).unit}")
        if model.at_bound(n, v):
            stuck.append(f"{n} = {v:.4g}")
    if unseen:
        lines.append(f"  note: {', '.join(unseen)}: no sd predicted. The plan works from the steer's response, "
                     "which carries nothing about a constant (it acts at 0 Hz; a fit finds it from the runs' means), "
                     "nor about a combination of parameters that moves it alike (then the drive cannot tell them "
                     "apart: another speed or manoeuvre may)")
    if stuck:
        lines.append(f"  note: {', '.join(stuck)} at the edge of the plausible range: the values assumed hold no "
                     "such effect (a run fitted for them showed none), so the sd predicted for it means little; "
                     "give the value you expect (vehicle file [params]) or leave the effect out")
    sugg = suggestions(model, params, manoeuvres, noise, targets)
    for s_ in sugg:
        lines.append("  " + s_)
    model_error = "residuals" in noise_source
    if not model_error:
        lines.append("  note: sensor noise only: this assumes the model is exactly the car, and predicts the least "
                     "spread a fit can have. Model error adds spread and bias that this plan does not see (README, "
                     "'Performance', and docs/bench.md); --noise-from RUN with a run that drove plans from the "
                     "residuals of a fit to it, which include the model error's spread")
    doc = {"model": model.name, "noise": noise_source, "includes_model_error": model_error,
           "estimator": pred["estimator"],
           "manoeuvres": [vars(m) for m in manoeuvres],
           "params": {n: {"value": float(params[n]),
                          "predicted_sd": float(pred["sd"][n]) if np.isfinite(pred["sd"][n]) else None,
                          "unit": model.param(n).unit} for n in pred["names"]},
           "suggestions": sugg, "warnings": list(warnings)}
    return "\n".join(lines), doc
