"""A faithful re-implementation of study (1)'s dynamic identification, for comparison:
H1 frequency responses, the bicycle's transfer functions (no sensor dynamics, as in the
study), the coherence-weighted squared complex error normalised per output by its mean
magnitude, minimised by Nelder-Mead (MATLAB fminsearch) over Cf, Cr, Iz.

``sensor_model=True`` (``--sensor-model``) gives the method the same measurement model
stid has: each model response is passed through the first-order output filter the run
declares (``run.meta["sensor_chain"]``: {"ay": Hz, "r": Hz}, 0 = none), i.e. multiplied
by 1 / (1 + j f / f_c). That is not in the study; it separates what the study's cost and
optimiser do from what the missing sensor dynamics do.

    python -m benchmarks.study_method RUN... --vehicle V.toml [--sensor-model]   # prints Cf Cr Iz
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy import optimize


def bicycle_frf(Cf, Cr, Iz, m, a, b, vx, f):
    """ay/delta and r/delta of the linear bicycle (study 1, eq. 16-23)."""
    s = 2j * np.pi * f
    A = np.array([[-(Cf + Cr) / (m * vx), -vx - (a * Cf - b * Cr) / (m * vx)],
                  [-(a * Cf - b * Cr) / (Iz * vx), -(a * a * Cf + b * b * Cr) / (Iz * vx)]])
    B = np.array([Cf / m, a * Cf / Iz])
    out = np.empty((2, len(f)), complex)
    for k, sk in enumerate(s):
        x = np.linalg.solve(sk * np.eye(2) - A, B)
        vy_dot = sk * x[0]
        out[0, k] = vy_dot + vx * x[1]
        out[1, k] = x[1]
    return out


def sensor_frf(sensors, f) -> np.ndarray:
    """(2, n_f): the first-order output filters 1 / (1 + j f / f_c) of ay and r (f_c 0: none)."""
    out = np.ones((2, len(f)), complex)
    for o, name in enumerate(("ay", "r")):
        fc = float((sensors or {}).get(name, 0.0) or 0.0)
        if fc > 0:
            out[o] = 1.0 / (1.0 + 1j * np.asarray(f) / fc)
    return out


def study_cost(theta, frfs, m, a, b, sensor_model=False):
    Cf, Cr, Iz = theta
    if min(theta) <= 0:
        return 1e30
    J = 0.0
    for fr in frfs:
        Hm = bicycle_frf(Cf, Cr, Iz, m, a, b, fr.vx, fr.f)
        if sensor_model:
            Hm = Hm * sensor_frf(getattr(fr, "sensors", None), fr.f)
        for o in range(2):
            J += np.sum(np.abs(Hm[o] - fr.H[o]) ** 2 * fr.coh[o]) / np.mean(np.abs(fr.H[o]))
    return J


def fit_study(frfs, vehicle, x0=None, sensor_model=False):
    m, a, b = vehicle.mass, vehicle.a, vehicle.b
    g = 9.81
    if x0 is None:  # the same normalised starting point stid uses (8 /rad, Iz = m a b / 2)
        x0 = [8 * m * g * b / (a + b), 8 * m * g * a / (a + b), 0.5 * m * a * b]
    res = optimize.minimize(study_cost, x0, args=(frfs, m, a, b, sensor_model), method="Nelder-Mead",
                            options={"xatol": 1e-6, "fatol": 1e-10, "maxiter": 4000, "maxfev": 8000})
    return dict(zip(("Cf", "Cr", "Iz"), res.x)), res


def main(argv=None) -> int:
    from stid.fit import dataset
    from stid.fit.frf import estimate_frf
    from stid.load import load_runs
    from stid.vehicle_file import load_vehicle

    ap = argparse.ArgumentParser(prog="benchmarks.study_method")
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--vehicle", required=True)
    ap.add_argument("--sensor-model", action="store_true",
                    help="pass the model through the runs' declared sensor filters (not in the study)")
    args = ap.parse_args(argv)
    v = load_vehicle(args.vehicle)
    frfs = [estimate_frf(s) for s in dataset.dynamic_stretches(load_runs(args.runs, v))]
    p, _ = fit_study(frfs, v, sensor_model=args.sensor_model)
    print(" ".join(f"{k} {val:.6g}" for k, val in p.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
