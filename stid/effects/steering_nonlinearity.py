from stid.lazy_numpy import np

from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class SteeringNonlinearity(Effect):
    """Road-wheel angle delta = delta_cmd (1 + k3 delta_cmd^2) for the logged steer delta_cmd.

    Why a cubic: the servo horn, the tie rods and the steering arms form a linkage whose
    transmission changes with angle (the horn's tip moves on a circle, the arms sit at an
    Ackermann angle); each wheel's angle is then a smooth function of the servo angle
    with even and odd terms, but the left and right wheels are mirror images, so their
    mean, the single track's road-wheel angle, is odd in the command. The steering
    calibration fixes the slope at straight ahead, so the first term beyond it is the
    cube. A servo saver that gives under load is a compliance (linear in the side force),
    not this.
    """

    name = "steering_nonlinearity"
    stage = "input"
    steer_place = "linkage"  # it turns the servo's output (after its lag and trim), not the command
    params = (Param("k3", "1/rad^2", "cubic steering-linkage coefficient: the road-wheel angle is "
                    "delta_cmd (1 + k3 delta_cmd^2); k3 < 0 degressive, > 0 progressive",
                    0.0, -5.0, 5.0, log=False, zero=0.0),)
    physics = ("The road-wheel angle is not proportional to the servo command: the linkage from servo horn "
               "through tie rods to the steering arms transmits a different ratio at large angles (and the "
               "mean of the left and right wheels is odd in the command), so delta = delta_cmd (1 + k3 "
               "delta_cmd^2). The bicycle model, which takes the logged steer as the wheel angle, is then "
               "right for small steer and wrong by the same fraction at large steer at every speed.")
    signature = ("residuals of yaw rate and lateral acceleration grow with |steer| (not with |ay|): the "
                 "same steer amplitude fails by the same fraction at every speed, and the residual follows "
                 "the cube of the steer")
    confused_with = {"tyre_saturation": "drive the same steer amplitudes at a low and a high speed: a "
                                        "linkage error scales with |steer| at every speed, tyre saturation "
                                        "with |ay| (so only at the speed where ay is large)"}

    def steer_map(self, delta_cmd, p, ctx):
        d = np.asarray(delta_cmd, float)
        return d * (1.0 + p["k3"] * d * d)
