"""One entry point for every method: ``fit(runs, vehicle, model, method)``.

Methods: ``steady`` (steady-state lines), ``freq`` (frequency responses, WLS;
needs constant-speed stretches), ``freq-study`` (study 1's coherence-weighted
cost, same need), ``time`` (output error, simulated at the measured speed, so
any speed profile),
``two-step`` (Cf, Cr from steady state, the rest from dynamics, as study 1
recommends; with no body-slip measurement the understeer gradient from steady
state constrains Cf and Cr instead), ``auto`` (two-step when the runs hold both
steady-state cornering and a stretch with steering, else what the data allow).
"""

from __future__ import annotations

import numpy as np

from stid import sensor_chain
from stid.errors import InputError
from stid.fit import dataset, nested, plausibility
from stid.fit.solver import ParamSpace
from stid.fit.steady_fit import fit_steady
from stid.fit.time_fit import fit_time
from stid.models.model import Model

METHODS = ("auto", "steady", "freq", "freq-study", "time", "two-step")


def fit(runs, vehicle, model_name: str = "bicycle", method: str = "auto", dynamic: str = "time",
        intervals: str = "model-error", stretches=None, init: dict | None = None, multistart: bool | None = None,
        inner=None):
    """Fit ``model_name`` to the runs by ``method``. ``intervals``: ``"model-error"`` (the
    default: also a block jackknife, so intervals cover model error that varies through the
    data) or ``"noise"`` (the sandwich alone; faster, for inner loops).

    This is the one fitting path of every command: ``fit``, ``compare``, each step of
    ``diagnose`` and ``report`` call it, so the same model on the same data gives the same
    parameters and fit percent in all of them. ``stretches``: the runs' time-domain
    stretches when the caller has built them already (diagnose builds them once for all its
    fits); ``init`` and ``multistart`` only choose where the solver starts, not what it
    minimises.

    A model with effects and no ``init`` starts from the bicycle's solution (stid.fit.nested;
    ``inner``: the bicycle's fit by the same method on the same runs, when the caller has it),
    and a time-domain fit that still ends below the bicycle says it did not converge."""
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if model_name.split("+")[0].strip() in ("greybox", "greybox-study"):
        if "+" in model_name:
            raise InputError("the grey-box model takes no effects; use bicycle+effect for those")
        if method not in ("auto", "time"):
            raise InputError("the grey-box model is fitted in the time domain only (--method time)")
        from stid.fit.greybox_fit import fit_greybox

        return fit_greybox(runs, vehicle, model_name.strip())
    model = Model(model_name, vehicle)
    if stretches is not None and method not in ("time", "auto"):
        raise ValueError("prebuilt stretches are the time-domain fit's")
    if method == "auto":
        method = "time" if stretches is not None else _choose(runs)
    if method == "time" and stretches is None:
        stretches = dataset.dynamic_stretches(runs)
    in_time = method == "time" or (method == "two-step" and dynamic == "time")
    contained = None
    if model.effects and init is None and method != "steady":
        contained = inner if inner is not None else fit(runs, vehicle, nested.BASE, method, dynamic, "noise",
                                                        stretches=stretches if method == "time" else None)
        if in_time:
            init = nested.best_start(model, contained.all_params(),
                                     stretches if stretches is not None else dataset.dynamic_stretches(runs))
        else:
            init = nested.effect_starts(model, contained.all_params())["effects at default"]
    result = _fit_model(model, runs, method, dynamic, intervals, stretches, init, multistart)
    kept_off = nested.bounds_keep_off(model)
    if kept_off:
        result.note(f"the vehicle file's [params] range keeps {', '.join(kept_off)} off the value where "
                    f"{'its effect vanishes' if len(kept_off) == 1 else 'their effects vanish'}: {model.name} does "
                    f"not contain {nested.BASE} and may fit worse than it")
    elif contained is not None and in_time and nested.worse_than(result, contained):
        zero = nested.effect_starts(model, contained.all_params())["effects at zero"]
        again = _fit_model(model, runs, method, dynamic, intervals, stretches, zero, False)
        result = again if again.loglik > result.loglik else result
        if nested.worse_than(result, contained):
            nested.say_worse(result, contained)
    for e in model.effects:
        if e.fit_note:
            result.note(f"{e.name}: {e.fit_note}")
    for w in sensor_chain.undeclared_warnings(runs, vehicle):
        result.warn(w)
    for w in plausibility.stiffness_warnings(result, runs, vehicle):
        result.warn(w)
    return result


def _fit_model(model, runs, method, dynamic, intervals, stretches, init, multistart):
    if method == "steady":
        return fit_steady(model, dataset.steady_points(runs))
    if method in ("freq", "freq-study"):
        # imported here: Welch spectra need scipy.signal, which costs half a second to import
        # (stid.fit.filters), and the time-domain fit does without it
        from stid.fit.freq_fit import fit_freq

        return fit_freq(model, dataset.dynamic_stretches(runs, constant_speed=True, method=method),
                        weighting="wls" if method == "freq" else "study", method_name=method, init=init)
    if method == "time":
        return fit_time(model, stretches, intervals=intervals, init=init, multistart=multistart)
    return two_step(model, runs, dynamic, intervals, init=init, multistart=multistart)


def _choose(runs) -> str:
    try:
        dataset.dynamic_stretches(runs)
        has_dyn, why_not = True, ""
    except InputError as e:
        has_dyn, why_not = False, str(e)
    pts = dataset.steady_points(runs)
    has_ss = len(pts.ay) >= 5 and np.ptp(pts.ay) >= 1.0 if len(pts.ay) else False
    if has_dyn and has_ss:
        return "two-step"
    if has_dyn:
        return "time"
    if has_ss:
        return "steady"
    # (why the dynamics cannot be fitted is the dynamic fit's to say: a run too short, too slow, or
    # without measurements to use, not only one without steering)
    raise InputError(f"the runs hold no steady-state cornering (circles with a slow speed sweep), and for the "
                     f"dynamics: {why_not}")


def two_step(model: Model, runs, dynamic: str = "time", intervals: str = "model-error", init: dict | None = None,
             multistart: bool | None = None):
    """Study 1's recommendation: stiffness from steady state first, the rest from dynamics
    (``init``, ``multistart``: where the dynamic fit starts)."""
    ss = fit_steady(model, dataset.steady_points(runs))
    stretches = dataset.dynamic_stretches(runs, constant_speed=dynamic != "time", method=dynamic)
    v = model.vehicle
    if "Cf" in ss.names:
        fixed = {"Cf": ss.value("Cf"), "Cr": ss.value("Cr")}
        space = ParamSpace(model, [n for n in model.param_names if n not in fixed], fixed)
    else:
        eta = ss.value("eta")
        # Cf follows from Cr and the understeer gradient: b/Cf = eta L/m + a/Cr
        def derived(p):
            return {"Cf": v.b / max(eta * v.L / v.mass + v.a / p["Cr"], 1e-12)}
        space = ParamSpace(model, [n for n in model.param_names if n != "Cf"], {}, derived=derived)
    if dynamic == "time":
        fitter = fit_time
    else:
        from stid.fit.freq_fit import fit_freq as fitter
    kw = {"intervals": intervals, "multistart": multistart} if dynamic == "time" else {}
    res = fitter(model, stretches, space=space, method_name=f"two-step (steady + {dynamic})", init=init, **kw)
    if "Cf" in ss.names:
        for i, n in enumerate(ss.names):
            se = ss.stderr[i]
            res.fixed[n] = (ss.values[i], "N/rad", f"from steady state (std. error {se:.4g})")
    else:
        p_hat = dict(zip(res.names, res.values))
        p_hat.update(space.derived(p_hat))
        # its standard error by the delta method, from eta's (the steady fit) and Cr's (the dynamic
        # fit, as wide as its printed interval: model error and geometry included; the two fits'
        # data differ, so their errors are taken as independent)
        D = eta * v.L / v.mass + v.a / p_hat["Cr"]
        se_cr = res.half95[res.names.index("Cr")] / 1.959964
        var = ((v.b * v.L / (v.mass * D ** 2)) ** 2 * ss.stderr[0] ** 2
               + (v.b * v.a / (D * p_hat["Cr"]) ** 2) ** 2 * se_cr ** 2)
        se_cf = f"std. error {np.sqrt(var):.4g}" if np.isfinite(var) else "no std. error: Cr has none"
        res.fixed["Cf"] = (p_hat["Cf"], "N/rad", f"from eta = {ss.value('eta'):.4g} rad/(m/s^2) and Cr ({se_cf})")
        res.extra["eta"] = ss.value("eta")
    res.extra["steady"] = ss
    for w in ss.warnings:
        if "Iz is not identifiable" not in w and "body slip" not in w:
            res.warn(w)
    return res
