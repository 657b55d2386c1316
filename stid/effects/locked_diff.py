from stid.models.effect import BodyLoad, Effect, register_effect
from stid.models.params import Param


def _rear_load_times_wheelbase(v):
    return 9.81 * v.mass * v.a / (v.a + v.b) * (v.a + v.b)


@register_effect
class LockedDiff(Effect):
    """A spool: both rear wheels turn at one speed, so in a turn the inner wheel is driven
    forward and the outer one braked, and their longitudinal forces make a yaw moment.

    With per-axle longitudinal stiffness Cx [N per unit slip] and rear track t, the
    wheels' slip difference is t r / vx and the moment Mz = -(Cx t^2 / 4) r / vx. The
    vehicle file holds what a user measures with scales and a tape (mass, a, b), not
    the track; yaw data identify only the product Cx t^2 anyway. So the coefficient is
    taken against the kinematic steer angle L r / vx (L = a + b, in the file):
    Mz = -k_diff L r / vx, k_diff [N m] is the spool's yaw moment per radian of it, and
    a user who knows the track reads Cx = 4 L k_diff / t^2.
    """

    name = "locked_diff"
    stage = "body"
    params = (Param("k_diff", "N m", "locked-differential yaw moment per radian of kinematic steer angle "
                    "L r / vx (Mz = -k_diff L r / vx; = Cx t^2 / (4 L) for rear track t and axle "
                    "longitudinal stiffness Cx)",
                    lambda v: 0.5 * _rear_load_times_wheelbase(v), 0.0,
                    lambda v: 10.0 * _rear_load_times_wheelbase(v), log=False, zero=0.0),)
    physics = ("A spool or locked differential makes both rear wheels turn at one speed. In a turn the inner "
               "wheel travels less than the outer, so it slips forward and the outer backward: their "
               "longitudinal forces make a yaw moment that opposes the yaw, Mz = -k_diff L r / vx (the slip "
               "difference across the axle is t r / vx). It damps yaw more at low speed and adds understeer.")
    signature = ("the yaw rate overshoots less and settles lower than the bicycle predicts, more so at low "
                 "speed (the moment goes with r / vx); steady cornering needs more steer (extra understeer); "
                 "lateral acceleration follows the yaw rate")
    confused_with = {"tyre_relaxation": "both slow the yaw response more at low speed; a steady circle "
                                        "separates them: a locked diff adds understeer there, relaxation "
                                        "does not change steady state"}

    def body_loads(self, p, ctx):
        return BodyLoad(Mz={"r": -p["k_diff"] * ctx.L / ctx.vx})
