"""The sentences a vehicle engineer reads for a candidate: what the residual shows, the
effect's parameter in units, and what adding it gained (stid.present lays them out)."""

from __future__ import annotations

import math

from stid.analysis.speeds import at_speeds, held_speeds, spans_speeds, speed_range, varies
from stid.models.effect import available_effects
from stid.models.params import unit_suffix
from stid.search.candidate import OUTS, Candidate


def explain(c: Candidate, base, stretches, res=None, adding: str = "Adding it") -> str:
    """One or two sentences with the numbers a vehicle engineer would check: the effect's
    parameters in ``res`` (default: the candidate's own fit), and what ``adding`` it gained
    over ``base`` (a pair's first says it was added with the second, its numbers are theirs)."""
    res = res if res is not None else c.result
    p = res.params()
    speeds = [v for v, _ in held_speeds(stretches)]
    if len(speeds) == 1 and varies(stretches):
        speeds = list(speed_range(stretches))  # (the relaxation's lag at either end of the range)
    gain = ", ".join(f"{o} {base.fit[o]:.1f}% -> {res.fit[o]:.1f}%" for o in OUTS)
    cls = available_effects()[c.effect]
    at = at_speeds(stretches)
    if c.effect == "actuator_lag":
        lead = (f"yaw-rate and lateral-acceleration residuals follow the steer by ~{1000 * p['tau_steer']:.0f} ms "
                f"{at}: steering servo lag, tau = {1000 * p['tau_steer']:.0f} ms")
    elif c.effect == "tyre_relaxation":
        lags = ", ".join(f"{1000 * p['sigma_f'] / v:.0f} ms at {v:.1f} m/s" for v in speeds)
        trend = ("the response lags more at low speed" if spans_speeds(stretches) else
                 "the response lags (one speed only: whether the lag shrinks as the speed rises, as a relaxation's "
                 "sigma/vx does and a servo's does not, needs a second speed)")
        lead = (f"{trend} ({lags} at the front axle): tyre relaxation, "
                f"sigma_f = {p['sigma_f']:.3f} m, sigma_r = {p['sigma_r']:.3f} m")
    elif c.effect == "accel_offset":
        # measured from the CG the vehicle file's a and b place: a CG elsewhere reads the same (a and b
        # swapped in a file: +2.4 cm named on a car whose accelerometer sits at its CG)
        lead = (f"only the ay residual has structure, and it follows the yaw acceleration: the accelerometer "
                f"sits {100 * p['x_acc']:+.1f} cm {'ahead of' if p['x_acc'] > 0 else 'behind'} the CG where the "
                "vehicle file's a and b put it (if it is mounted at the CG, a and b are wrong: weigh the axles)")
    elif c.effect == "body_roll":
        lead = (f"ay reads {100 * 9.81 * p['roll_gain']:.1f}% high in steady cornering with a resonance near "
                f"{p['roll_freq']:.1f} Hz; yaw rate fits: the body rolls "
                f"{math.degrees(p['roll_gain']) * 9.81:.1f} deg/g and tilts the accelerometer")
    elif c.effect == "tyre_saturation":
        lead = (f"the fit is good at low |ay| and fails toward the peaks: the tyres saturate, mu = {p['mu']:.2f} "
                f"(friction limit {9.81 * p['mu']:.1f} m/s^2)")
    elif c.effect == "sensor_bias":
        lead = (f"the residuals have a constant part unrelated to steer: gyro offset "
                f"{math.degrees(p['bias_r']):+.2f} deg/s, accelerometer offset {p['bias_ay']:+.3f} m/s^2 "
                "left after calibration")
    else:
        own = {n: v for n, v in p.items() if res.owners.get(n) == c.effect}
        ps = ", ".join(f"{n} = {v:.4g}{unit_suffix(res.units.get(n, ''))}" for n, v in own.items())
        shows = cls.signature if spans_speeds(stretches) else _without_speed_claims(cls.signature)
        lead = f"{shows}: {c.effect} ({ps}, {at})" if shows else f"{c.effect} ({ps}, {at})"
    text = f"{lead}. {adding}: {gain}."
    if c.separable_from:
        other, advice = next(iter(c.separable_from.items()))
        text += f" Cannot be told apart from {other} on this data: {advice}."
    return text


def _without_speed_claims(signature: str) -> str:
    """An effect's signature less its clauses (``;``-separated) about speed: on data that hold one
    speed the explanation says what this data show, and they show nothing of a change with speed."""
    return "; ".join(part.strip() for part in signature.split(";") if "speed" not in part)
