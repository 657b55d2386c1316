"""Parameter recovery on simulated data with known truth (firmware in the loop,
MCAP through the recorder), and study (1)'s structure on its passenger car."""

import numpy as np
import pytest

from simdata import TRUTH, random_steer_pair, sim_run
from stid.fit.fitting import fit
from stid.load import load_runs

BASE = {"Cf": TRUTH.Cf, "Cr": TRUTH.Cr, "Iz": TRUTH.Iz}
# The data each effect needs to show: saturation needs driving near the friction limit.
EFFECT_DATA = {"tyre_saturation": dict(steer_amp=0.07, bandwidth=2.0)}
EFFECT_TRUTH = {
    "actuator_lag": {"tau_steer": TRUTH.tau_steer},
    "tyre_relaxation": {"sigma_f": TRUTH.sigma_f, "sigma_r": TRUTH.sigma_r},
    "accel_offset": {"x_acc": TRUTH.x_acc},
    "body_roll": {"roll_gain": TRUTH.roll_gain, "roll_freq": TRUTH.roll_freq},
    "tyre_saturation": {"mu": TRUTH.mu},
    "sensor_bias": {"bias_r": TRUTH.bias_r, "bias_ay": TRUTH.bias_ay},
}


def rel_err(res, truth):
    p = res.all_params()
    return {k: abs(p[k] - v) / abs(v) for k, v in truth.items()}


@pytest.mark.parametrize("method", ["time", "freq"])
def test_clean_random_steer_within_3_percent(simdir, rc_vehicle, method):
    runs = load_runs(random_steer_pair(simdir), rc_vehicle)
    res = fit(runs, rc_vehicle, "bicycle", method)
    err = rel_err(res, BASE)
    assert max(err.values()) < 0.03, (err, res.table())
    assert res.fit["ay"] > 97 and res.fit["r"] > 97
    assert np.all(res.stderr > 0) and np.all(np.isfinite(res.stderr))


@pytest.mark.parametrize("effect", sorted(EFFECT_TRUTH))
def test_effect_in_the_model_recovers_base_within_5_percent(simdir, rc_vehicle, effect):
    runs = load_runs(random_steer_pair(simdir, (effect,), **EFFECT_DATA.get(effect, {})), rc_vehicle)
    plain = fit(runs, rc_vehicle, "bicycle", "time")
    res = fit(runs, rc_vehicle, f"bicycle+{effect}", "time")
    err = rel_err(res, BASE)
    assert max(err.values()) < 0.05, (err, res.table())
    # the effect's own parameters come back too (looser: they are smaller signals)
    eff_err = rel_err(res, EFFECT_TRUTH[effect])
    assert max(eff_err.values()) < 0.15, (eff_err, res.table())
    # and the error falls when the effect is added
    assert res.fit["ay"] + res.fit["r"] > plain.fit["ay"] + plain.fit["r"] + 1.0


def test_a_sensor_offset_interval_is_not_widened_by_the_offset_itself(simdir, rc_vehicle):
    """The large-angle geometry's check simulated the force response with the model's sensor
    offsets in it, so the exact-geometry change carried the offsets and widened bias_r's interval
    by bias_r itself: 0.0298 [-0.0008, 0.0603] rad/s (+-93.5 se), an interval that said the gyro
    may have no offset, where the data give +-0.0008."""
    runs = load_runs(random_steer_pair(simdir, ("sensor_bias",), **EFFECT_DATA.get("sensor_bias", {})), rc_vehicle)
    res = fit(runs, rc_vehicle, "bicycle+sensor_bias", "time")
    for name in ("bias_r", "bias_ay"):
        i = res.names.index(name)
        lo, hi = res.ci95[i]
        assert (hi - lo) / 2 < 10 * res.stderr[i] and lo > 0, (name, res.table())


def test_steady_state_circles_with_body_slip_give_cf_and_cr(simdir, rc_vehicle_csv):
    path = sim_run(simdir, "steady_circle", seed=3, speed=2.0, speed_end=7.0, duration=40, steer_amp=0.06,
                   csv=True, beta_sensor=0.002)
    res = fit(load_runs([path], rc_vehicle_csv), rc_vehicle_csv, "bicycle", "steady")
    err = rel_err(res, {"Cf": TRUTH.Cf, "Cr": TRUTH.Cr})
    assert max(err.values()) < 0.03, (err, res.table())
    assert any("Iz is not identifiable" in w for w in res.warnings)


def test_steady_state_without_body_slip_gives_the_understeer_gradient_and_says_so(simdir, rc_vehicle):
    path = sim_run(simdir, "steady_circle", seed=3, speed=2.0, speed_end=7.0, duration=40, steer_amp=0.06)
    res = fit(load_runs([path], rc_vehicle), rc_vehicle, "bicycle", "steady")
    eta_true = TRUTH.mass / TRUTH.L * (TRUTH.b / TRUTH.Cf - TRUTH.a / TRUTH.Cr)
    assert res.names == ["eta"]
    assert res.value("eta") == pytest.approx(eta_true, rel=0.05)
    assert any("beta is not measured" in w for w in res.warnings)


def test_double_lane_change_time_domain(simdir, rc_vehicle):
    paths = [sim_run(simdir, "double_lane_change", seed=s, speed=v, duration=8) for s, v in ((4, 4.0), (5, 5.0))]
    res = fit(load_runs(paths, rc_vehicle), rc_vehicle, "bicycle", "time")
    err = rel_err(res, BASE)
    assert max(err.values()) < 0.03, (err, res.table())


def test_two_step_with_body_slip_and_random_steer(simdir, rc_vehicle_csv):
    paths = [sim_run(simdir, "steady_circle", seed=3, speed=2.0, speed_end=7.0, duration=40, steer_amp=0.06,
                     csv=True, beta_sensor=0.002)]
    paths += [sim_run(simdir, "random_steer", seed=s, speed=v, csv=True, beta_sensor=0.002)
              for s, v in ((1, 4.0), (2, 6.0))]
    res = fit(load_runs(paths, rc_vehicle_csv), rc_vehicle_csv, "bicycle", "auto")
    assert res.method.startswith("two-step")
    assert "Cf" in res.fixed and "Cr" in res.fixed
    assert max(rel_err(res, BASE).values()) < 0.03, res.table()


def test_relaxation_and_servo_lag_from_one_speed_are_flagged(simdir, rc_vehicle):
    runs = load_runs([random_steer_pair(simdir, ("actuator_lag",))[0]], rc_vehicle)
    res = fit(runs, rc_vehicle, "bicycle+actuator_lag+tyre_relaxation", "freq")
    assert any("cannot be told apart from one speed" in w for w in res.warnings)


def test_json_contract(simdir, rc_vehicle):
    runs = load_runs(random_steer_pair(simdir), rc_vehicle)
    doc = fit(runs, rc_vehicle, "bicycle", "freq").to_json()
    assert doc["model"] == "bicycle"
    assert set(doc["params"]) == {"Cf", "Cr", "Iz"}
    assert doc["params"]["Cf"]["unit"] == "N/rad"
    for p in doc["params"].values():
        assert p["stderr"] > 0 and p["ci95"][0] < p["value"] < p["ci95"][1]
    assert set(doc["fit"]) == {"ay", "r"}
    assert len(doc["correlation"]["matrix"]) == 3


# -- study (1): the passenger car ---------------------------------------------------

@pytest.fixture(scope="module")
def passenger(tmp_path_factory):
    """Study 1's unloaded car: axle loads 784/522.5 kg; wheelbase chosen 2.6 m."""
    from hil_sim.manoeuvres import Plan
    from hil_sim.truth_csv import write_truth_run
    from hil_sim.vehicle import CarParams
    from stid.vehicle_file import Vehicle

    d = tmp_path_factory.mktemp("study1")
    L, m = 2.6, 784 + 522.5
    a = L * 522.5 / m
    car = CarParams(mass=m, a=a, b=L - a, Iz=1353.7, Cf=67473.0, Cr=91611.0, sigma_f=0.902, sigma_r=0.365)
    write_truth_run(d / "ss.csv", car, ("tyre_relaxation",),
                    Plan(name="steady_circle", duration=60, speed=8.0, speed_end=28.0, steer_amp=0.03, still=1,
                         run_up=4), seed=1)
    write_truth_run(d / "rs1.csv", car, ("tyre_relaxation",),
                    Plan(name="random_steer", duration=60, speed=25.0, steer_amp=0.01, bandwidth=2.0, still=1,
                         run_up=6), seed=2)
    write_truth_run(d / "rs2.csv", car, ("tyre_relaxation",),
                    Plan(name="random_steer", duration=60, speed=15.0, steer_amp=0.015, bandwidth=2.0, still=1,
                         run_up=5), seed=3)
    veh = Vehicle(name="passenger car", mass=m, a=a, b=L - a,
                  sensors={"accel_bandwidth_hz": 0, "gyro_bandwidth_hz": 0})
    ss = load_runs([d / "ss.csv"], veh)
    rs = load_runs([d / "rs1.csv", d / "rs2.csv"], veh)
    return car, veh, ss, rs


def test_study1_every_method_recovers_the_passenger_car(passenger):
    car, veh, ss, rs = passenger
    truth = {"Cf": car.Cf, "Cr": car.Cr, "Iz": car.Iz, "sigma_f": car.sigma_f, "sigma_r": car.sigma_r}
    steady = fit(ss, veh, "bicycle", "steady")
    assert max(rel_err(steady, {"Cf": car.Cf, "Cr": car.Cr}).values()) < 0.03
    for method in ("freq", "time"):
        res = fit(rs, veh, "bicycle+tyre_relaxation", method)
        err = rel_err(res, truth)
        assert max(err[k] for k in ("Cf", "Cr", "Iz")) < 0.05, (method, err)
        assert max(err[k] for k in ("sigma_f", "sigma_r")) < 0.25, (method, err)
    two = fit(ss + rs, veh, "bicycle+tyre_relaxation", "two-step")
    assert max(rel_err(two, truth).values()) < 0.05, two.table()


def test_study1_two_step_beats_dynamic_only_without_relaxation(passenger):
    """The study's finding: with a dynamic model that lacks relaxation, taking Cf and Cr
    from steady state beats fitting everything to the dynamics."""
    car, veh, ss, rs = passenger
    dyn = fit(rs, veh, "bicycle", "freq")
    two = fit(ss + rs, veh, "bicycle", "two-step")
    e_dyn = rel_err(dyn, {"Cf": car.Cf, "Cr": car.Cr, "Iz": car.Iz})
    e_two = rel_err(two, {"Cf": car.Cf, "Cr": car.Cr, "Iz": car.Iz})
    assert e_dyn["Cf"] > 0.10 and e_dyn["Cr"] > 0.10  # dynamics alone: stiffness badly biased
    assert e_two["Cf"] < 0.01 and e_two["Cr"] < 0.01
    # (whether two-step also fits the responses better depends on the data set: it did on one
    # version of the simulator and not on the next, so it is not claimed)
    # what two-step cannot fix: with Cf, Cr held right, Iz absorbs the missing relaxation
    # (+31% here; the study saw +16%). Only the model with relaxation gets Iz right.
    assert e_two["Iz"] > 0.1


def test_study2_greybox_on_a_double_lane_change_with_wheel_slip(tmp_path, rc_vehicle_csv):
    """The nonlinear vx/vy/r model with Cx, Cy and wheel slips (study 2), fitted in the
    time domain to lane changes with their run-up (the drive slips the rear wheels).
    The study's single Cy holds here because the simulated car's axles are made equal;
    the per-axle form and the project's own car are in test_greybox.py."""
    from hil_sim.manoeuvres import Plan
    from hil_sim.record import record
    from hil_sim.run import SimConfig
    from hil_sim.vehicle import CarParams

    car = CarParams(Cf=440.0, Cr=440.0)  # study 2 assumes one Cy for all four tyres
    paths = []
    for seed, v in ((1, 4.0), (2, 5.0)):
        cfg = SimConfig(plan=Plan(name="double_lane_change", duration=8, speed=v, still=0.5, run_up=3),
                        seed=seed, car=car, wheel_speeds=True)
        record(cfg, tmp_path / f"{seed}.mcap", csv_path=tmp_path / f"{seed}.csv")
        paths.append(tmp_path / f"{seed}.csv")
    res = fit(load_runs(paths, rc_vehicle_csv), rc_vehicle_csv, "greybox-study", "time")
    err = rel_err(res, {"Cy": car.Cf / 2, "Iz": car.Iz, "Cx": car.Cx / 2})
    assert err["Cy"] < 0.03 and err["Iz"] < 0.05 and err["Cx"] < 0.03, res.table()
    assert res.fit["vx"] > 97 and res.fit["ay"] > 97 and res.fit["r"] > 97
    assert not any("one Cy" in w for w in res.warnings), res.warnings


def test_greybox_needs_wheel_speeds(simdir, rc_vehicle):
    from stid.errors import InputError

    with pytest.raises(InputError, match="wheel speeds"):
        fit(load_runs(random_steer_pair(simdir)[:1], rc_vehicle), rc_vehicle, "greybox")


def test_two_step_without_body_slip_gives_cf_from_eta_with_its_standard_error(passenger):
    """Without beta the steady state gives only the understeer gradient, and Cf follows from it
    and the dynamic fit's Cr. It was printed as 'fixed' with no uncertainty at all; its standard
    error now comes from eta's and Cr's (delta method), and the truth lies within its 95%."""
    import dataclasses
    import re

    car, veh, ss, rs = passenger
    runs = [dataclasses.replace(r, beta=None) for r in ss + rs]
    two = fit(runs, veh, "bicycle+tyre_relaxation", "two-step")  # the passenger car has relaxation
    cf, _, why = two.fixed["Cf"]
    se = float(re.search(r"std\. error ([0-9.e+-]+)", why).group(1))
    eta = two.extra["eta"]
    i = two.names.index("Cr")
    lo, hi = two.ci95[i]
    D = eta * veh.L / veh.mass + veh.a / two.values[i]
    dcr = veh.b * veh.a / (D * two.values[i]) ** 2 * (hi - lo) / (2 * 1.959964)
    assert dcr <= se <= 5 * dcr + 0.05 * cf, (se, dcr)  # Cr's share, and eta's on top
    assert abs(cf - car.Cf) < 1.96 * se + 0.01 * car.Cf, (cf, se, car.Cf)


def test_a_steady_line_fitted_across_the_tyres_saturation_is_said_with_the_linear_gradient():
    """Steady circles written here from plain physics: the axle forces of steady cornering (m ay b/L
    front, m ay a/L rear) through a tanh tyre law, the steer L/R + alpha_f - alpha_r. A trial's
    circle ramped to 2 g and gave eta three times the car's linear gradient, without a word. Past
    0.4 g, where the line bends, it is said, with the gradient of the points within the linear range;
    linear tyres over the same range are not."""
    from stid.fit.dataset import SteadyPoints
    from stid.fit.steady_fit import fit_steady
    from stid.models.model import Model
    from stid.vehicle_file import Vehicle

    m, a, b, Cf, Cr, mu, g = 4.2, 0.152, 0.108, 180.0, 380.0, 1.0, 9.81  # (understeering: the front saturates first)
    L = a + b
    veh = Vehicle(name="tanh car", mass=m, a=a, b=b)
    rng = np.random.default_rng(7)
    R = 2.5
    ay = np.linspace(0.5, 0.9 * mu * g, 60)
    vx = np.sqrt(ay * R)

    def slip(F, C, Fz, saturating):
        return np.arctanh(F / (mu * Fz)) * mu * Fz / C if saturating else F / C

    eta_true = m / L * (b / Cf - a / Cr)
    for saturating in (True, False):
        af = slip(m * ay * b / L, Cf, m * g * b / L, saturating)
        ar = slip(m * ay * a / L, Cr, m * g * a / L, saturating)
        steer = L / R + af - ar + 1e-4 * rng.standard_normal(len(ay))
        res = fit_steady(Model("bicycle", veh), SteadyPoints(steer, ay, vx / R, vx, None))
        said = [w for w in res.warnings if "past the tyres' linear range" in w]
        if not saturating:
            assert not said and res.value("eta") == pytest.approx(eta_true, rel=0.05), res.warnings
            continue
        assert said, (res.value("eta"), eta_true, res.warnings)
        within = float(said[0].split("eta = ")[1].split(" ")[0])
        assert within == pytest.approx(eta_true, rel=0.25), (said[0], eta_true)  # (0.4 g is not quite linear)
        assert abs(res.value("eta") / eta_true - 1) > 0.25  # the line over all of it is off
