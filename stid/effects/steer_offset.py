from stid.lazy_numpy import np

from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class SteerOffset(Effect):
    """Servo trim: the road wheels point ``delta0`` off straight ahead when the logged
    command is zero, delta = delta_cmd + delta0.

    Why a steer map and not an input offset of the linear system: the offset must reach
    the tyres through the dynamics at every speed of a run (at speed vx it turns the car
    at r = vx delta0 / (L (1 + K vx^2)) and ay = vx r), which the measured-speed simulator
    does when the offset is in the steer it is given. A constant is invisible to the
    frequency-response fit (it removes means): that fit says delta0 is not identified.

    The same mean residual as ``sensor_bias``: both add constants to r and ay at one speed.
    A trim's constants are a turn's, ay = vx r (the kinematics the data carry hold), and
    grow with speed as the turn's yaw rate does; a sensor's offsets do neither
    (stid.analysis.kinematics tells them apart).
    """

    name = "steer_offset"
    stage = "input"
    # A trim is the servo's (its centre pulse, or a horn a spline off): the linkage turns the trimmed
    # angle. Before or after the servo's lag is the same for a constant (the lag's gain at rest is 1).
    steer_place = "servo"
    params = (Param("delta0", "rad", "road-wheel angle at zero steering command (servo trim), "
                    "positive to the left", 0.0, -0.15, 0.15, log=False, zero=0.0, multistart=False),)
    physics = ("The servo's centre does not put the road wheels straight: a horn a spline off, tie rods of "
               "unequal length or a trim the driver set make the wheels point delta0 off when the command is "
               "zero, so the road-wheel angle is delta_cmd + delta0. Every RC car has some; the car then "
               "turns at a steady yaw rate vx delta0 / (L (1 + K vx^2)) with ay = vx r, as in any turn.")
    signature = ("the residuals of yaw rate and lateral acceleration have a non-zero mean that does not "
                 "correlate with steer; their means are a turn's (mean ay = vx mean r) and grow with speed, "
                 "so the kinematic check r - ay/vx sees no offset")
    confused_with = {"sensor_bias": "drive at a second speed: a trim's offsets grow with speed as a turn's yaw "
                                    "rate does and keep ay = vx r, a sensor's offsets stay the same and break "
                                    "it (r - ay/vx then averages the gyro's offset); or log a stretch of "
                                    "straight driving with the wheels checked straight"}

    def steer_map(self, delta_cmd, p, ctx):
        return np.asarray(delta_cmd, float) + p["delta0"]
