from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class SensorBias(Effect):
    name = "sensor_bias"
    stage = "output"
    params = (
        Param("bias_r", "rad/s", "yaw-rate gyro offset left after calibration", 0.0, -0.5, 0.5,
              log=False, zero=0.0),
        Param("bias_ay", "m/s^2", "lateral accelerometer offset left after calibration", 0.0, -3.0, 3.0,
              log=False, zero=0.0),
    )
    physics = ("A MEMS gyro's zero-rate output and an accelerometer's zero-g output drift with "
               "temperature: an offset left after the stand-still calibration adds a constant to "
               "every reading. It does not depend on steer, speed or frequency.")
    signature = ("the residuals have a non-zero mean (their spectrum peaks at 0 Hz) that does not "
                 "correlate with steer; the gyro's offset shows in the kinematics too: r - ay/vx averages "
                 "bias_r - bias_ay/vx, which a car's motion alone keeps at zero")
    confused_with = {"steer_offset": "drive at a second speed: a sensor's offsets stay the same, a steering "
                                     "trim's grow with speed and keep ay = vx r; or stand the car still after "
                                     "the run, where a sensor's offset remains and a trim's vanishes"}

    def apply(self, sys, p, ctx):
        sys = sys.copy()
        sys.offsets["r"] = sys.offsets.get("r", 0.0) + p["bias_r"]
        sys.offsets["ay"] = sys.offsets.get("ay", 0.0) + p["bias_ay"]
        return sys
