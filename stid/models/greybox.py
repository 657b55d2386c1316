"""The nonlinear grey-box model of study (2) (after MATLAB's IDNLGREY vehicle example):
states vx, vy, r; four tyres with linear longitudinal and lateral stiffness Cx, Cy
(the same for every tyre); longitudinal slips from measured wheel speeds; slip
angles from the states:

    s_i     = (w_i R - vx) / max(vx, w_i R)                       (i = fl, fr, rl, rr)
    alpha_f = delta - atan((vy + a r)/vx),  alpha_r = -atan((vy - b r)/vx)
    m (vx' - vy r) = (Fxfl + Fxfr) cos d - (Fyfl + Fyfr) sin d + Fxrl + Fxrr - CA vx^2
    m (vy' + vx r) = (Fxfl + Fxfr) sin d + (Fyfl + Fyfr) cos d + Fyrl + Fyrr
    Iz r'          = a ((Fxfl + Fxfr) sin d + (Fyfl + Fyfr) cos d) - b (Fyrl + Fyrr)

Inputs: steer and the four wheel speeds; outputs vx, ay (= vy' + vx r) and r.
Unlike the linear models it covers speed changes (braking, the run-up of a lane
change), at the price of a sequential integration.
"""

from __future__ import annotations

import math

import numpy as np

from stid.models.params import Param

G = 9.81

GREYBOX_PARAMS = (
    Param("Cx", "N/(unit slip) per tyre", "longitudinal tyre stiffness", lambda v: 8 * v.mass * G / 4,
          lambda v: 0.2 * v.mass * G / 4, lambda v: 200 * v.mass * G / 4),
    Param("Cy", "N/rad per tyre", "lateral tyre stiffness (cornering stiffness per tyre)",
          lambda v: 8 * v.mass * G / 4, lambda v: 0.3 * v.mass * G / 4, lambda v: 60 * v.mass * G / 4),
    Param("Iz", "kg m^2", "yaw moment of inertia", lambda v: 0.5 * v.mass * v.a * v.b,
          lambda v: 0.05 * v.mass * v.a * v.b, lambda v: 5 * v.mass * v.a * v.b),
    Param("CA", "N s^2/m^2", "air resistance coefficient", 0.0, 0.0, lambda v: 0.05 * v.mass, log=False, zero=0.0),
)
WHEELS = ("w_fl", "w_fr", "w_rl", "w_rr")


class GreyBox:
    name = "greybox"
    effects: list = []
    nonlinear = True

    def __init__(self, vehicle):
        self.vehicle = vehicle
        self.params = list(GREYBOX_PARAMS)

    @property
    def param_names(self):
        return [p.name for p in self.params]

    def param(self, name):
        return next(p for p in self.params if p.name == name)

    def defaults(self):
        return {p.name: p.value("init", self.vehicle) for p in self.params}

    def bounds(self, name):
        p = self.param(name)
        return p.value("lower", self.vehicle), p.value("upper", self.vehicle)

    def owner(self, name):
        return "greybox"

    def simulate(self, p: dict, t: np.ndarray, steer: np.ndarray, wheels: np.ndarray, x0) -> np.ndarray:
        """RK4 over the sample grid with inputs linear between samples: (n, 3) of vx, ay, r."""
        v = self.vehicle
        m, a, b, R = v.mass, v.a, v.b, v.wheel_radius
        Cx, Cy, Iz, CA = p["Cx"], p["Cy"], p["Iz"], p["CA"]

        def rhs(x, d, w):
            vx, vy, r = x
            vxe = vx if vx > 0.3 else 0.3
            fx = []
            for wi in w:
                u = wi * R
                den = u if u > vxe else vxe
                fx.append(Cx * (u - vxe) / den)
            af = d - math.atan((vy + a * r) / vxe)
            ar = -math.atan((vy - b * r) / vxe)
            Fyf, Fyr = 2 * Cy * af, 2 * Cy * ar
            Fxf, Fxr = fx[0] + fx[1], fx[2] + fx[3]
            cd, sd = math.cos(d), math.sin(d)
            lat_f = Fxf * sd + Fyf * cd
            dvx = (Fxf * cd - Fyf * sd + Fxr - CA * vx * vx) / m + vy * r
            dvy = (lat_f + Fyr) / m - vx * r
            dr = (a * lat_f - b * Fyr) / Iz
            return dvx, dvy, dr, (lat_f + Fyr) / m

        n = len(t)
        out = np.empty((n, 3))
        x = list(x0)
        st = steer.tolist()
        W = wheels.T.tolist()
        for i in range(n):
            d0, w0 = st[i], W[i]
            k1 = rhs(x, d0, w0)
            out[i] = (x[0], k1[3], x[2])
            if i == n - 1:
                break
            h = t[i + 1] - t[i]
            d1, w1 = st[i + 1], W[i + 1]
            dm = 0.5 * (d0 + d1)
            wm = [0.5 * (p0 + p1) for p0, p1 in zip(w0, w1)]
            k2 = rhs([x[j] + 0.5 * h * k1[j] for j in range(3)], dm, wm)
            k3 = rhs([x[j] + 0.5 * h * k2[j] for j in range(3)], dm, wm)
            k4 = rhs([x[j] + h * k3[j] for j in range(3)], d1, w1)
            x = [x[j] + h / 6 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j]) for j in range(3)]
            if not all(map(math.isfinite, x)) or abs(x[1]) > 1e3:
                out[i + 1:] = np.nan
                break
        return out
