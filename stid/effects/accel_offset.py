from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class AccelOffset(Effect):
    name = "accel_offset"
    stage = "output"
    params = (Param("x_acc", "m", "accelerometer position ahead of the CG", 0.0,
                    lambda v: -(v.a + v.b), lambda v: v.a + v.b, log=False, zero=0.0),)
    physics = ("An accelerometer mounted x_acc ahead of the centre of gravity also feels the yaw "
               "acceleration: ay_sensor = ay + x_acc r'. It adds a term that rises with frequency "
               "(r' is r times j omega) to the lateral acceleration only; yaw rate is unaffected.")
    signature = ("only the lateral-acceleration residual has structure; it correlates with the yaw "
                 "acceleration r' and grows with frequency; the yaw-rate fit is already good")

    def apply(self, sys, p, ctx):
        sys = sys.copy()
        sys.add_to_output("ay", source="r_dot", gain=p["x_acc"])
        return sys
