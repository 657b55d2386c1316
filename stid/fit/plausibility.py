"""Is a fitted axle stiffness a tyre's? Cornering stiffness against the axle's load.

A tyre's cornering stiffness grows with its load, and per newton of load it lies in a
narrow band whatever the car's size (the normalised cornering stiffness, or cornering
coefficient, C / Fz per axle):

- scale cars (F1TENTH-class 1:10): 4-10 /rad (HARDWARE.md);
- road tyres: 8-18 % of the load per degree for bias-ply, 11-19 % for radial, up to 25-30 %
  for low-profile tyres (Gillespie, Fundamentals of Vehicle Dynamics, pp. 347-355): 4.6-17
  /rad; study 1's passenger car: 8.8 /rad front, 17.9 /rad rear.

An axle's effective stiffness, which the single track fits, is lower than its tyres' (roll
and compliance steer, load transfer between the two tyres), and a fitted value has its
interval: PLAUSIBLE_PER_RAD is that band widened by a factor of two at both ends. A value
outside it is not a tyre's: the linear model took something it lacks for soft (or stiff)
tyres, and no longer run changes that. What it took is said where the data tell: the
steering calibration, measured without a model from the car's own held-steer stretches
(stid.analysis.held_steer).
"""

from __future__ import annotations

from stid.analysis import held_steer

G = 9.81
PLAUSIBLE_PER_RAD = (2.0, 35.0)
AXLES = {"Cf": "front", "Cr": "rear"}


def axle_loads(vehicle) -> dict:
    """Static load per axle [N] from the mass and the CG position."""
    return {"Cf": vehicle.mass * G * vehicle.b / vehicle.L, "Cr": vehicle.mass * G * vehicle.a / vehicle.L}


def _interval(result, name):
    try:
        ci = result.to_json()["params"].get(name, {}).get("ci95")
    except (KeyError, AttributeError):
        return None
    return tuple(ci) if ci is not None else None


def stiffness_warnings(result, runs, vehicle) -> list[str]:
    """One line when a fitted axle stiffness is outside PLAUSIBLE_PER_RAD of its axle's load,
    with what the runs' held steer says about the steering calibration; [] otherwise (and for
    a model without Cf, Cr)."""
    params = result.all_params()
    if not all(n in params for n in AXLES):
        return []
    lo, hi = PLAUSIBLE_PER_RAD
    loads = axle_loads(vehicle)
    odd, parts, verdicts = [], [], []
    for name, axle in AXLES.items():
        c = params[name] / loads[name]
        if lo <= c <= hi:
            continue
        odd.append(c < lo)
        ci = _interval(result, name)
        reach = ""
        if ci is None:  # fixed by the steady-state step, or not determined
            verdicts.append(None)
        else:
            c_lo, c_hi = ci[0] / loads[name], ci[1] / loads[name]
            verdicts.append(c_hi < lo or c_lo > hi)
            if not verdicts[-1]:
                reach = f"; its interval reaches {c_hi if c < lo else c_lo:.3g} /rad"
        parts.append(f"{name} {params[name]:.4g} N/rad is {c:.2g} /rad of the {axle} axle's load "
                     f"({loads[name]:.3g} N{reach})")
    if not parts:
        return []
    soft = all(odd)
    kind = "soft" if soft else ("stiff" if not any(odd) else "soft and stiff")
    line = (" and ".join(parts) + f", where tyres give {lo:g}-{hi:g} /rad (scale cars 4-10; "
            "docs/plausibility.md): ")
    if any(verdicts):
        line += (f"no tyre is that {kind}: the model takes something it lacks for {kind} tyres, and a longer run "
                 "will not change that. ")
    elif False in verdicts:
        line += (f"not a tyre's value, though the interval does not rule one out; if it holds, the model takes "
                 f"something it lacks for {kind} tyres. ")
    else:
        line += f"not a tyre's value: if the data hold it, the model takes something it lacks for {kind} tyres. "
    return [line + _steering_words(runs, vehicle)]


def _steering_words(runs, vehicle) -> str:
    from stid.input_checks import SCALE_TOLERANCE

    gain = held_steer.steering_gain(runs, vehicle.L, PLAUSIBLE_PER_RAD)
    if gain is None:
        return ("The runs hold the steer for under a second while moving slowly and gently, so the steering "
                "calibration could not be checked from them (L r / (vx steer), held): check it, the mass and a, b, "
                "and what lags between the steer and the response (stid diagnose)")
    if not SCALE_TOLERANCE[0] <= gain.speed_ratio <= SCALE_TOLERANCE[1]:
        return (f"Held, the car turned {gain.gain:.2f} of the logged steer ({gain.words()}), but ay is "
                f"{gain.speed_ratio:.2f} of vx r there: the speed or a sensor's scale reads wrong, which moves "
                "that ratio and every fitted value; check those first")
    if gain.far_from_one():
        return (f"The wheels turn {gain.gain:.2f} of the logged steer ({gain.words()}): check the steering "
                "calibration ([steering] gain)")
    return (f"The held steer does not point at the steering calibration: the car turned {gain.gain:.2f} of the "
            f"logged steer ({gain.words()}); check the mass and a, b, and what lags between the steer and the response "
            "(stid diagnose)")
