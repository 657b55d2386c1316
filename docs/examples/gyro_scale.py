"""The identifier's side: a gyro whose sensitivity is off by a factor 1 + k."""

from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class GyroScale(Effect):
    name = "gyro_scale"
    stage = "output"
    params = (Param("gyro_scale_err", "-", "relative error of the gyro sensitivity",
                    0.0, -0.3, 0.3, log=False, zero=0.0),)
    physics = ("The gyro's sensitivity differs from the datasheet value by a factor 1 + k, "
               "so the measured yaw rate is (1 + k) r at every frequency and speed.")
    signature = ("the yaw-rate residual is proportional to the yaw rate itself, at every "
                 "frequency and speed; the lateral acceleration misfits only through the car's "
                 "parameters, bent to fit the wrong yaw rate")

    def apply(self, sys, p, ctx):
        sys = sys.copy()
        sys.add_to_output("r", source="r", gain=p["gyro_scale_err"])
        return sys
