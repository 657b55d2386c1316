"""The nonlinear grey-box model of study (2) (after MATLAB's IDNLGREY vehicle example):
states vx, vy, r; four tyres with linear longitudinal and lateral stiffness;
longitudinal slips from measured wheel speeds; slip angles from the states:

    s_i     = (w_i R - vx) / vx                                   (i = fl, fr, rl, rr)
    alpha_f = delta - atan((vy + a r)/vx),  alpha_r = -atan((vy - b r)/vx)
    Fx_i = Cx s_i,  Fyf = Cyf alpha_f,  Fyr = Cyr alpha_r         (Fyf, Fyr per axle)
    m (vx' - vy r) = (Fxfl + Fxfr) cos d - Fyf sin d + Fxrl + Fxrr - CA vx^2
    m (vy' + vx r) = (Fxfl + Fxfr) sin d + Fyf cos d + Fyr
    Iz r'          = a ((Fxfl + Fxfr) sin d + Fyf cos d) - b Fyr

Inputs: steer and the four wheel speeds; outputs vx, ay (= vy' + vx r) and r.
Unlike the linear models it covers speed changes (braking, the run-up of a lane
change), at the price of a sequential integration.

Two forms:

- ``greybox``: one lateral stiffness per axle, ``Cyf`` and ``Cyr`` [N/rad per axle],
  as everywhere else in stid. A car's axles differ (load, tyres, toe, compliance),
  and the yaw balance a - b Cyr/Cyf is what the lateral dynamics are about.
- ``greybox-study``: the study's single ``Cy`` [N/rad per tyre] for all four tyres
  (Fyf = Fyr/alpha = 2 Cy). On a car whose axles differ it cannot match both the
  understeer and the yaw response, and the fit bends Iz to compensate; kept for
  comparison with the study (the fit warns when the data say so).

The slip is the ISO 8855 longitudinal slip (wheel's circumferential speed minus
vx, over vx). Cx is per tyre [N per unit slip], as in the study: the front tyres of
a rear-driven car roll freely and carry no slip, so only the driven axle shows it
(the axle's stiffness is 2 Cx). The model uses the hub speed of the CG for every
wheel (no track width): the left and right slips then differ by -/+ r t/(2 vx),
which cancels in each axle's force.
"""

from __future__ import annotations

import math

import numpy as np

from stid.models.params import Param

G = 9.81


def _axle(scale):
    """Init and bounds of a lateral stiffness (per axle: scale 1; per tyre: 0.5)."""
    return (lambda v: scale * 8 * v.mass * G / 2, lambda v: scale * 0.3 * v.mass * G / 2,
            lambda v: scale * 60 * v.mass * G / 2)


CX = Param("Cx", "N/(unit slip) per tyre", "longitudinal tyre stiffness", lambda v: 8 * v.mass * G / 4,
           lambda v: 0.2 * v.mass * G / 4, lambda v: 200 * v.mass * G / 4)
IZ = Param("Iz", "kg m^2", "yaw moment of inertia", lambda v: 0.5 * v.mass * v.a * v.b,
           lambda v: 0.05 * v.mass * v.a * v.b, lambda v: 5 * v.mass * v.a * v.b)
CA = Param("CA", "N s^2/m^2", "air resistance coefficient", 0.0, 0.0, lambda v: 0.05 * v.mass, log=False, zero=0.0)
PER_AXLE_PARAMS = (
    CX,
    Param("Cyf", "N/rad per axle", "front lateral (cornering) stiffness, both tyres together", *_axle(1.0)),
    Param("Cyr", "N/rad per axle", "rear lateral (cornering) stiffness, both tyres together", *_axle(1.0)),
    IZ, CA,
)
STUDY_PARAMS = (
    CX,
    Param("Cy", "N/rad per tyre", "lateral tyre stiffness, the same for all four tyres (study 2); "
          "per axle 2 Cy", *_axle(0.5)),
    IZ, CA,
)
GREYBOX_PARAMS = PER_AXLE_PARAMS  # the default form
WHEELS = ("w_fl", "w_fr", "w_rl", "w_rr")
MODEL_NAMES = ("greybox", "greybox-study")
VX_MIN = 0.3  # m/s: below walking pace slip and slip angle lose their meaning


class GreyBox:
    effects: list = []
    nonlinear = True

    def __init__(self, vehicle, form: str = "greybox"):
        if form not in MODEL_NAMES:
            raise ValueError(f"unknown grey-box form {form!r}; choose one of {', '.join(MODEL_NAMES)}")
        self.vehicle = vehicle
        self.name = form
        self.per_axle = form == "greybox"
        self.params = list(PER_AXLE_PARAMS if self.per_axle else STUDY_PARAMS)

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

    def axle_stiffness(self, p: dict) -> tuple[float, float]:
        """Front and rear lateral stiffness per axle [N/rad]."""
        if self.per_axle:
            return p["Cyf"], p["Cyr"]
        return 2 * p["Cy"], 2 * p["Cy"]

    def simulate(self, p: dict, t: np.ndarray, steer: np.ndarray, wheels: np.ndarray, x0) -> np.ndarray:
        """RK4 over the sample grid with inputs linear between samples: (n, 3) of vx, ay, r.

        ``wheels`` is (4, n) of fl, fr, rl, rr [rad/s]. With the slip over vx, an axle's
        force needs only the sum of its wheels' circumferential speeds, so the inputs
        (and their midpoints) are reduced to steer and two sums before the loop."""
        v = self.vehicle
        m, a, b, R = v.mass, v.a, v.b, v.wheel_radius
        Cx, Iz, CA = p["Cx"], p["Iz"], p["CA"]
        Cf, Cr = self.axle_stiffness(p)
        uf = (wheels[0] + wheels[1]) * R  # m/s, summed over the axle
        ur = (wheels[2] + wheels[3]) * R
        mid = lambda x: (0.5 * (x[:-1] + x[1:])).tolist()  # noqa: E731
        st, UF, UR = steer.tolist(), uf.tolist(), ur.tolist()
        stm, UFm, URm = mid(steer), mid(uf), mid(ur)
        h_all = np.diff(t).tolist()
        cos, sin, atan = math.cos, math.sin, math.atan
        im, iI = 1.0 / m, 1.0 / Iz

        def rhs(vx, vy, r, d, u_f, u_r):
            vxe = vx if vx > VX_MIN else VX_MIN
            Fxf = Cx * (u_f - 2 * vx) / vxe
            Fxr = Cx * (u_r - 2 * vx) / vxe
            Fyf = Cf * (d - atan((vy + a * r) / vxe))
            Fyr = -Cr * atan((vy - b * r) / vxe)
            cd, sd = cos(d), sin(d)
            lat_f = Fxf * sd + Fyf * cd
            ay = (lat_f + Fyr) * im
            return (Fxf * cd - Fyf * sd + Fxr - CA * vx * vx) * im + vy * r, ay - vx * r, \
                (a * lat_f - b * Fyr) * iI, ay

        n = len(t)
        out = np.full((n, 3), np.nan)
        vx, vy, r = (float(x) for x in x0)
        for i in range(n):
            d0, f0, r0 = st[i], UF[i], UR[i]
            k1 = rhs(vx, vy, r, d0, f0, r0)
            out[i] = (vx, k1[3], r)
            if i == n - 1:
                break
            h = h_all[i]
            hh = 0.5 * h
            dm, fm, rm = stm[i], UFm[i], URm[i]
            k2 = rhs(vx + hh * k1[0], vy + hh * k1[1], r + hh * k1[2], dm, fm, rm)
            k3 = rhs(vx + hh * k2[0], vy + hh * k2[1], r + hh * k2[2], dm, fm, rm)
            k4 = rhs(vx + h * k3[0], vy + h * k3[1], r + h * k3[2], st[i + 1], UF[i + 1], UR[i + 1])
            h6 = h / 6
            vx += h6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            vy += h6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            r += h6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
            if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(r)) or abs(vy) > 1e3:
                break
        return out
