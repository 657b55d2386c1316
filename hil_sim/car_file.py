"""Another car for the simulator (``stid-sim --car FILE``): its truth from a TOML file.

The keys are ``hil_sim.vehicle.CarParams``' fields, in its units (SI: kg, m, kg m^2,
N/rad per axle, s, Hz); any key left out keeps the reference 1:8 car's value. A 1:10
car, for instance::

    mass = 3.7        # kg
    a = 0.15          # m, CG to front axle
    b = 0.18          # m, CG to rear axle
    Iz = 0.05         # kg m^2
    Cf = 220.0        # N/rad, front axle
    Cr = 300.0        # N/rad, rear axle
    sigma_f = 0.04    # m, relaxation lengths (tyre_relaxation)
    sigma_r = 0.04

Read here, not by ``stid``'s vehicle file: the simulator's truth is written apart from
the identifier. An unknown key, a value that is not a number or a car that cannot
exist (a non-positive mass, inertia or stiffness) is an error that names it.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import fields, replace
from pathlib import Path

from hil_sim.vehicle import CarParams

# values a car cannot have zero or below (the others, offsets and angles, may be signed)
POSITIVE = ("mass", "a", "b", "Iz", "Cf", "Cr", "wheel_radius", "track", "Cx", "tau_steer", "steer_rate_max",
            "sigma_f", "sigma_r", "roll_freq", "mu", "mf_shape", "steer_us_per_rad", "servo_period_us")


def load_car(path) -> CarParams:
    """The car in the TOML file ``path``: the reference car with the file's values."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"--car {path}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"--car {path} is not valid TOML ({e})") from None
    known = {f.name: f.type for f in fields(CarParams)}
    values = {}
    for key, v in doc.items():
        if key not in known:
            near = difflib.get_close_matches(key, known, n=1)
            raise ValueError(f"--car {path}: unknown key {key!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                             + "; the keys are hil_sim.vehicle.CarParams' fields (mass, a, b, Iz, Cf, Cr, ...)")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"--car {path}: {key} must be a number, got {v!r}")
        if key in POSITIVE and v <= 0:
            raise ValueError(f"--car {path}: {key} must be positive, got {v}")
        values[key] = int(v) if known[key] in (int, "int") else float(v)
    return replace(CarParams(), **values)
