from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class ActuatorLag(Effect):
    name = "actuator_lag"
    stage = "input"
    steer_place = "servo"  # the linkage (steering_nonlinearity, a trim's horn) takes the servo's output
    params = (Param("tau_steer", "s", "steering servo time constant", 0.05, 1e-6, 0.5, zero=1e-7),)
    physics = ("The steering servo follows its command as a first-order lag: the road-wheel angle "
               "obeys delta' = (delta_cmd - delta)/tau_steer. RC servos take 0.05-0.16 s; the logger "
               "records the command, not the wheel, so every response starts tau_steer late.")
    signature = ("residuals of yaw rate and lateral acceleration follow the steer by the same delay at "
                 "every speed; the model's phase error grows with frequency and does not change with speed")
    confused_with = {"tyre_relaxation": "drive the same random steer at a second speed: relaxation lag "
                                        "scales with 1/speed, servo lag does not"}

    def apply(self, sys, p, ctx):
        tau = p["tau_steer"]
        return sys.series_input("delta", [[-1 / tau]], [[1 / tau]], [[1.0]], [[0.0]], ["delta_w"], "delta")
