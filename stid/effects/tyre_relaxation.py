from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class TyreRelaxation(Effect):
    name = "tyre_relaxation"
    stage = "tyre"
    params = (
        Param("sigma_f", "m", "front tyre relaxation length", lambda v: 0.15 * (v.a + v.b),
              lambda v: 1e-5 * (v.a + v.b), lambda v: 3.0 * (v.a + v.b), zero=1e-7),
        Param("sigma_r", "m", "rear tyre relaxation length", lambda v: 0.15 * (v.a + v.b),
              lambda v: 1e-5 * (v.a + v.b), lambda v: 3.0 * (v.a + v.b), zero=1e-7),
    )
    physics = ("A tyre builds its side force over a rolling distance, the relaxation length sigma: "
               "Fy' = (vx/sigma)(C alpha - Fy). The lag sigma/vx is a time at one speed but a distance "
               "of travel at all speeds; on scale cars sigma is about a wheel radius (a few ms at speed).")
    signature = ("the model leads the measurement at high frequency, in yaw rate and in lateral "
                 "acceleration; the lag is sigma/vx, so it shrinks as speed rises")
    confused_with = {"actuator_lag": "drive the same random steer at a second speed: relaxation lag "
                                     "scales with 1/speed, servo lag does not"}

    def tyre_options(self, p, ctx):
        return {"sigma_f": p["sigma_f"], "sigma_r": p["sigma_r"]}
