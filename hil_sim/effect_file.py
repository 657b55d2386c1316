"""A user's own truth-side effect, loaded from a Python file (``stid-sim --effect-file FILE``).

The file is the car's physics, written apart from the identifier's effect class (it
must not import ``stid``): a hidden effect is only a test if the two were written
separately. It defines any of three functions, each called by the simulator with
SI values and ISO 8855 signs (x forward, y left, left turns positive):

``steer_angle(delta, car) -> delta``
    The front road-wheel angle [rad] from the angle the steering would give without
    the effect, at every integration step (linkage, compliance, a steering gyro).
``body_loads(state, car) -> (Fy, Mz)``
    An extra lateral force [N] and yaw moment [N m] on the body at the centre of
    gravity, from ``state`` (a dict of ``vx``, ``vy`` [m/s], ``r`` [rad/s], ``delta``
    [rad]) at every integration step (a locked differential, aerodynamics).
``sensor_signals(t, signals, car) -> signals``
    What the sensors feel, before their noise, filters and ADC: ``signals`` holds
    arrays ``ax``, ``ay``, ``az`` [m/s^2] and ``r`` [rad/s] on the time grid ``t`` [s];
    return the dict with the changed arrays (a scale error, a misaligned sensor).

``car`` is the simulated car's ``hil_sim.vehicle.CarParams`` (mass, a, b, Iz, Cf, Cr,
track, ...). An optional ``NAME`` string names the effect in the truth file.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

HOOKS = ("steer_angle", "body_loads", "sensor_signals")


@dataclass(frozen=True)
class TruthEffect:
    name: str
    path: str
    steer_angle: Callable | None = None
    body_loads: Callable | None = None
    sensor_signals: Callable | None = None


def load_effect_file(path) -> TruthEffect:
    """Load ``path``; a missing file, a file that fails to run or one without any of the
    hooks is a ValueError whose message says what to fix (stid-sim prints it in one line)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--effect-file {path}: no such file; give the path of a Python file that defines "
                         f"{', '.join(HOOKS[:-1])} or {HOOKS[-1]}")
    spec = importlib.util.spec_from_file_location(f"hil_sim_truth_effect_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as e:  # the user's code: say which file and what, in one line
        raise ValueError(f"--effect-file {path} failed to load ({type(e).__name__}: {e})") from None
    hooks = {h: getattr(module, h, None) for h in HOOKS}
    bad = [h for h, f in hooks.items() if f is not None and not callable(f)]
    if bad:
        raise ValueError(f"--effect-file {path}: {', '.join(bad)} must be a function")
    if not any(hooks.values()):
        raise ValueError(f"--effect-file {path} defines none of {', '.join(HOOKS)}: define at least one "
                         "(see hil_sim/effect_file.py)")
    wrapped = {h: _reported(f, h, path) for h, f in hooks.items() if f is not None}
    return TruthEffect(name=str(getattr(module, "NAME", path.stem)), path=str(path), **wrapped)


RETURNS = {"steer_angle": "the road-wheel angle, one number [rad]",
           "body_loads": "a pair (Fy [N], Mz [N m])",
           "sensor_signals": "the dict of signals it was given (arrays ax, ay, az, r of the same length)"}


def _reported(fn, hook, path):
    """``fn``, with an error inside the user's code, or a result of the wrong shape (a
    forgotten ``return``), turned into one line naming the file and hook."""
    check = {"steer_angle": _one_number, "body_loads": _two_numbers, "sensor_signals": _signals}[hook]

    def call(*args):
        # what the result must look like, taken before the user's code can change the arguments
        # (sensor_signals edits the dict it is given and returns it)
        given = {k: np.shape(v) for k, v in args[1].items()} if hook == "sensor_signals" else None
        try:
            out = fn(*args)
        except Exception as e:
            raise ValueError(f"--effect-file {path}: {hook} raised {type(e).__name__}: {e}") from None
        try:
            got = check(out, given)
        except (TypeError, ValueError):
            got = "nothing (a missing return?)" if out is None else f"{type(out).__name__} {_short(out)}"
            raise ValueError(f"--effect-file {path}: {hook} must return {RETURNS[hook]}; it returned {got}") from None
        values = got.values() if isinstance(got, dict) else np.atleast_1d(got)
        if not all(np.all(np.isfinite(np.asarray(v, float))) for v in values):
            # (the run was written with them: an accelerometer at its ADC limit for 7489 samples, no word)
            at = f" at vx = {args[0]['vx']:.3g} m/s" if hook == "body_loads" and isinstance(args[0], dict) else ""
            if at and not abs(args[0]["vx"]) < 1e3:
                at += (" (the car's motion had run away by then: a load that grows with the motion it causes "
                       "diverges; check its signs, ISO 8855)")
            raise ValueError(f"--effect-file {path}: {hook} returned nan or inf{at}: it must give finite values "
                             "everywhere the car drives")
        return got

    return call


def _short(x) -> str:
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


def _one_number(out, given) -> float:
    return float(out)


def _two_numbers(out, given) -> tuple:
    fy, mz = out
    return float(fy), float(mz)


def _signals(out, given: dict) -> dict:
    if not isinstance(out, dict) or set(out) != set(given):
        raise TypeError
    if any(np.shape(v) != given[k] for k, v in out.items()):
        raise ValueError
    return out
