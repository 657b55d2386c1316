import math

from stid.models.effect import G, Effect, register_effect
from stid.models.params import Param


@register_effect
class BodyRoll(Effect):
    name = "body_roll"
    stage = "output"
    params = (
        Param("roll_gain", "rad/(m/s^2)", "steady-state roll angle per lateral acceleration",
              0.003, 0.0, 0.05, log=False, zero=0.0),
        Param("roll_freq", "Hz", "undamped roll natural frequency", 3.0, 0.5, 20.0),
        Param("roll_damping", "-", "roll damping ratio", 0.5, 0.05, 2.0),
    )
    physics = ("The sprung mass rolls on its suspension as a damped second-order system driven by "
               "lateral acceleration: phi'' + 2 zeta w phi' + w^2 phi = w^2 k_phi ay. The body-fixed "
               "accelerometer tilts with it and reads ay cos(phi) + g sin(phi): a gain error of "
               "g k_phi in steady state and a resonance at the roll frequency. Yaw rate is unaffected.")
    signature = ("the lateral-acceleration residual is proportional to ay in steady state (a gain "
                 "error) and peaks near the roll frequency; the yaw-rate fit is already good")
    confused_with = {"accel_offset": "both change only ay; a steady-state circle separates them: roll "
                                     "scales steady ay, an offset accelerometer does not"}

    def apply(self, sys, p, ctx):
        w = 2 * math.pi * p["roll_freq"]
        z = p["roll_damping"]
        k = p["roll_gain"]
        sys = sys.add_states(["phi", "phi_dot"], [[0.0, 1.0], [-w * w, -2 * z * w]],
                             {"ay_cg": [0.0, w * w * k]})
        sys.add_to_output("ay", state="phi", gain=G)
        return sys
