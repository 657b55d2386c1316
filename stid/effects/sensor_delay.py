from functools import cache
from math import factorial

from stid.lazy_numpy import np

from stid.models.effect import Effect, register_effect
from stid.models.params import Param

PADE_ORDER = 4


@cache  # (built once, on first use: the catalogue is imported by every command, even --help)
def _pade_unit(order: int = PADE_ORDER):
    """State space of the (order, order) Pade approximant of exp(-x), in x = s * delay."""
    c = np.array([factorial(2 * order - k) * factorial(order) / (factorial(2 * order) * factorial(k)
                  * factorial(order - k)) for k in range(order + 1)])
    num = (c * (-1.0) ** np.arange(order + 1))[::-1]  # P(-x), highest power first
    den = c[::-1]
    # controller canonical form, as scipy.signal.tf2ss writes it (by hand: importing
    # scipy.signal costs half a second of every command, see stid.fit.filters)
    num, den = num / den[0], den / den[0]
    D = num[0]
    A = np.zeros((order, order))
    A[0] = -den[1:]
    A[1:, :-1] = np.eye(order - 1)
    B = np.zeros((order, 1))
    B[0, 0] = 1.0
    C = (num[1:] - D * den[1:])[None, :]
    return A, B, C, np.array([[D]])


@register_effect
class SensorDelay(Effect):
    """The sensor channels reach the log ``delay_s`` later than the steer they answer.

    Why a Pade block and not a shift of the sampled output: the model must stay one
    linear system at each speed, so that the frequency fit, the planner and the
    measured-speed (LPV) simulator, which rebuilds the matrices at several speeds,
    all take the delay with no change of theirs; a resampled output would exist in
    the time-domain path only. The (4, 4) Pade approximant of exp(-s d) is all-pass
    (the gain is exact) and its phase is within 0.04 deg of the delay's for
    omega d <= 3 (0.4 deg at 4): for a 50 ms delay, exact to 10 Hz, beyond the
    band a random-steer run excites. Delaying every sensor is, for a linear model,
    the same as delaying the steer, so the block sits in front of the model's input;
    a delay also commutes with a static steer map (a linkage), so it stays in the
    linear model behind any map (``steer_place`` "linkage", the default).
    Only sensors late relative to the steer (delay_s > 0) are modelled: a steer
    logged after the sensors would be a non-causal block.
    """

    name = "sensor_delay"
    stage = "input"
    params = (Param("delay_s", "s", "time by which the sensor channels lag the steer channel in the log",
                    0.01, 1e-4, 0.1, zero=1e-7),)
    physics = ("The logging pipeline delays the sensor channels against the steer by a pure time offset "
               "delay_s (a sensor's digital filter or FIFO, a sample taken later than the steer it is "
               "stamped with): every response appears delay_s late with its shape and size unchanged.")
    signature = ("residuals of yaw rate and lateral acceleration follow the steer by the same time at every "
                 "speed; the phase error grows linearly with frequency while the gain is right (a servo lag "
                 "also lowers the gain at high frequency)")
    confused_with = {"actuator_lag": "steer faster than the servo's corner frequency 1/(2 pi tau_steer) (2.7 Hz "
                                     "for 60 ms): a chirp to 5 Hz, sharp steps or random steer to 4 Hz. A servo "
                                     "lag rounds a step and lowers the gain above that frequency, a pure delay "
                                     "shifts the response unchanged"}

    def apply(self, sys, p, ctx):
        d = p["delay_s"]
        names = [f"delay_{k}" for k in range(PADE_ORDER)]
        A, B, C, D = _pade_unit()
        return sys.series_input("delta", A / d, B / d, C, D, names, "delta")
