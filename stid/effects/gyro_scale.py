from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class GyroScale(Effect):
    """The gyro's sensitivity differs from the datasheet's: r_meas = (1 + k_gyro) r.

    Why it is identifiable at all: stid converts the gyro's volts with the datasheet's
    3.3 mV/(deg/s) (LISY300AL; parts differ by several percent), and a yaw-rate gain alone
    would be taken up by the car's parameters. The accelerometer carries the same motion:
    ay = vy' + vx r at the centre of gravity, with vx measured, so a gyro that reads k high
    breaks that kinematic tie between the two sensors at every speed, which no choice of
    Cf, Cr and Iz restores.
    """

    name = "gyro_scale"
    stage = "output"
    params = (Param("k_gyro", "-", "relative error of the gyro's sensitivity: the yaw rate is read as "
                    "(1 + k_gyro) r", 0.0, -0.3, 0.3, log=False, zero=0.0, multistart=False),)
    physics = ("A MEMS gyro's sensitivity differs from part to part and with supply and temperature; stid "
               "converts its output with the datasheet's value, so the measured yaw rate is (1 + k_gyro) r at "
               "every frequency and speed. The accelerometer sees the same motion through ay = vy' + vx r, "
               "which ties the two sensors' scales together.")
    signature = ("the yaw-rate residual is proportional to the yaw rate itself at every frequency and speed; "
                 "in steady turning r reads (1 + k_gyro) ay / vx; the lateral acceleration misfits only "
                 "through the car's parameters, bent to fit the wrong yaw rate")
    confused_with = {"body_roll": "both change one sensor's scale; a steady circle at two speeds separates them: "
                                  "roll scales ay and resonates near the roll frequency, a gyro scale error "
                                  "scales r alike at every frequency"}

    def apply(self, sys, p, ctx):
        sys = sys.copy()
        sys.add_to_output("r", source="r", gain=p["k_gyro"])
        return sys
