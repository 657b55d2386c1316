from stid.lazy_numpy import np

from stid.models.effect import Effect, register_effect
from stid.models.params import Param


@register_effect
class TyreSaturation(Effect):
    name = "tyre_saturation"
    stage = "tyre"
    params = (Param("mu", "-", "tyre-road friction coefficient", 1.0, 0.1, 3.0, zero=1e6,
                    multistart=False),)
    physics = ("Side force levels off at the friction limit: Fy = mu Fz tanh(C alpha / (mu Fz)) per "
               "axle, linear for small slip and bounded by mu Fz. Below about 40% of the limit the "
               "bicycle model is exact; beyond it the car needs more steer than the model predicts.")
    signature = ("residuals grow with |ay|: the fit is good in the linear range and fails near the "
                 "friction limit; the model overshoots the measured peaks of ay and r")
    # measured by a new user's trial on 2026-11-27: the simulator's tyres follow the Magic Formula
    # (shape 1.3, mu 0.9); fitted with this law at 6 deg of steer, 7 of 32 intervals missed the truth
    fit_note = ("its law is tanh; a car's tyres have their own shape (the Magic Formula's, say), and the "
                "difference is an error common to all the data that no interval here holds: on simulated "
                "Magic-Formula tyres (mu 0.9) this law's mu came out 0.86-0.88, and Cf 1-3% low where a servo "
                "lag was fitted with it")

    def force_correction(self, alpha_f, alpha_r, p, ctx):
        Fzf, Fzr = ctx.axle_loads()
        mu = p["mu"]
        out = []
        for alpha, C, Fz in ((alpha_f, p["Cf"], Fzf), (alpha_r, p["Cr"], Fzr)):
            lin = C * alpha
            lim = mu * Fz
            out.append(lim * np.tanh(lin / lim) - lin)
        return out
