"""The identifier's side: an accelerometer whose sensitivity is off by a factor 1 + k."""

from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class AccelScale(Effect):
    name = "accel_scale"
    stage = "output"
    params = (Param("accel_scale_err", "-", "relative error of the accelerometer's sensitivity",
                    0.0, -0.3, 0.3, log=False, zero=0.0),)
    physics = ("The accelerometer's sensitivity differs from the datasheet value by a factor 1 + k, "
               "so the measured lateral acceleration is (1 + k) ay at every frequency and speed.")
    signature = ("the lateral-acceleration residual is proportional to ay itself, at every "
                 "frequency and speed; the yaw rate misfits only through the car's parameters, "
                 "bent to fit the wrong ay")

    def apply(self, sys, p, ctx):
        sys = sys.copy()
        sys.add_to_output("ay", source="ay", gain=p["accel_scale_err"])
        return sys
