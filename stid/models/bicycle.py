"""The linear single-track ("bicycle") model, the base every effect extends.

States lateral velocity vy [m/s] and yaw rate r [rad/s] (plus the axle side
forces when tyres relax). Axle side forces from slip angles with cornering
stiffness per axle [N/rad]:

    alpha_f = delta - (vy + a r)/vx,   alpha_r = -(vy - b r)/vx
    m (vy' + vx r) = Fyf + Fyr,        Iz r' = a Fyf - b Fyr
    ay = vy' + vx r = (Fyf + Fyr)/m    (at the centre of gravity)

With relaxation lengths sigma_f, sigma_r the forces lag their steady value:
Fy' = vx/sigma (C alpha - Fy) (study 1, section 2.3). Inputs: the front
road-wheel angle ``delta`` and additive force corrections ``dFf``, ``dFr`` used by
nonlinear tyre effects.

Body loads (``stid.models.effect.BodyLoad``, the effects' ``"body"`` stage) add a
lateral force Fy and a yaw moment Mz, linear in vy, r and delta, to the right-hand
sides: m (vy' + vx r) = Fyf + Fyr + Fy, Iz r' = a Fyf - b Fyr + Mz. The
accelerometer at the CG feels Fy too (ay = (Fyf + Fyr + Fy)/m).
"""

from __future__ import annotations

import numpy as np

from stid.models.effect import Context
from stid.models.linsys import LinSys
from stid.models.params import Param

OUTPUTS = ["ay", "r", "r_dot", "ay_cg", "alpha_f", "alpha_r", "vy"]


def _fz(v, axle):
    G = 9.81
    return v.mass * G * (v.b if axle == "f" else v.a) / (v.a + v.b)


BASE_PARAMS = (
    Param("Cf", "N/rad", "front axle cornering stiffness", lambda v: 8 * _fz(v, "f"),
          lambda v: 0.3 * _fz(v, "f"), lambda v: 60 * _fz(v, "f")),
    Param("Cr", "N/rad", "rear axle cornering stiffness", lambda v: 8 * _fz(v, "r"),
          lambda v: 0.3 * _fz(v, "r"), lambda v: 60 * _fz(v, "r")),
    Param("Iz", "kg m^2", "yaw moment of inertia", lambda v: 0.5 * v.mass * v.a * v.b,
          lambda v: 0.05 * v.mass * v.a * v.b, lambda v: 5 * v.mass * v.a * v.b),
)


def _load_rows(loads, n):
    """Sum of the body loads as rows over the states (vy, r first) and the inputs (delta first)."""
    Fy_x, Fy_u, Mz_x, Mz_u = np.zeros(n), np.zeros(3), np.zeros(n), np.zeros(3)
    for ld in loads:
        for coef, row_x, row_u in ((ld.Fy, Fy_x, Fy_u), (ld.Mz, Mz_x, Mz_u)):
            row_x[0] += coef.get("vy", 0.0)
            row_x[1] += coef.get("r", 0.0)
            row_u[0] += coef.get("delta", 0.0)
    return Fy_x, Fy_u, Mz_x, Mz_u


def bicycle(p: dict, ctx: Context, sigma_f: float | None = None, sigma_r: float | None = None,
            loads=()) -> LinSys:
    m, a, b, vx = ctx.mass, ctx.a, ctx.b, ctx.vx
    Cf, Cr, Iz = p["Cf"], p["Cr"], p["Iz"]
    # slip angles as rows over [vy, r] and [delta]
    af_x, af_u = np.array([-1 / vx, -a / vx]), 1.0
    ar_x, ar_u = np.array([-1 / vx, b / vx]), 0.0
    relax = sigma_f is not None
    if relax:
        states = ["vy", "r", "Fyf", "Fyr"]
        # forces are states: F = [0 0 1 0] x, [0 0 0 1] x
        Ff_x, Ff_u = np.array([0, 0, 1.0, 0]), np.zeros(3)
        Fr_x, Fr_u = np.array([0, 0, 0, 1.0]), np.zeros(3)
        af_x, ar_x = np.r_[af_x, 0, 0], np.r_[ar_x, 0, 0]
    else:
        states = ["vy", "r"]
        Ff_x, Ff_u = Cf * af_x, np.array([Cf * af_u, 1.0, 0.0])
        Fr_x, Fr_u = Cr * ar_x, np.array([0.0, 0.0, 1.0])
    n = len(states)
    # extra forces on the body (the "body" stage) beside the axle forces; Fy acts at the CG
    Fy_x, Fy_u, Mz_x, Mz_u = _load_rows(loads, n)
    A = np.zeros((n, n))
    B = np.zeros((n, 3))
    ay_x, ay_u = (Ff_x + Fr_x + Fy_x) / m, (Ff_u + Fr_u + Fy_u) / m
    A[0] = ay_x
    A[0, 1] -= vx
    B[0] = ay_u
    A[1] = (a * Ff_x - b * Fr_x + Mz_x) / Iz
    B[1] = (a * Ff_u - b * Fr_u + Mz_u) / Iz
    if relax:
        kf, kr = vx / sigma_f, vx / sigma_r
        A[2] = kf * Cf * af_x
        A[2, 2] -= kf
        B[2] = [kf * Cf * af_u, kf, 0.0]
        A[3] = kr * Cr * ar_x
        A[3, 3] -= kr
        B[3] = [0.0, 0.0, kr]
    # rows in the order of OUTPUTS: ay, r, r_dot, ay_cg, alpha_f, alpha_r, vy
    C = np.zeros((len(OUTPUTS), n))
    D = np.zeros((len(OUTPUTS), 3))
    C[0] = C[3] = ay_x
    D[0] = D[3] = ay_u
    C[1, 1] = 1.0
    C[2], D[2] = A[1], B[1]
    C[4], D[4, 0] = af_x, af_u
    C[5], D[5, 0] = ar_x, ar_u
    C[6, 0] = 1.0
    return LinSys(A, B, C, D, states, ["delta", "dFf", "dFr"], list(OUTPUTS))
