"""The simulated car obeys the textbook where it should, and each effect changes
what it should (checked against formulas written here, not against stid)."""

import math

import numpy as np
import pytest

from hil_sim import manoeuvres, sensors, vehicle
from hil_sim.manoeuvres import Plan
from hil_sim.run import SimConfig, simulate_run

CAR = vehicle.CarParams()


def drive(name, effects=(), **plan):
    cfg = SimConfig(plan=Plan(name=name, **plan), effects=effects, seed=1)
    return simulate_run(cfg)


def test_steady_state_yaw_gain_matches_linear_theory():
    run = drive("steady_circle", duration=12, speed=2.0, speed_end=6.0, steer_amp=0.05)
    tr = run.traj
    m, a, b, L = CAR.mass, CAR.a, CAR.b, CAR.L
    K = m / L * (b / CAR.Cf - a / CAR.Cr)  # understeer gradient, rad per m/s^2
    for v in (3.0, 4.0, 5.0):
        i = np.argmin(np.abs(tr.vx - v) + 10 * (tr.t < run.cfg.plan.still + run.cfg.plan.run_up + 2))
        gain = tr.r[i] / tr.delta[i]
        expected = tr.vx[i] / (L + K * tr.vx[i] ** 2)
        assert gain == pytest.approx(expected, rel=0.02)


def test_double_lane_change_passes_the_gates():
    run = drive("double_lane_change", duration=8, speed=4.0)
    tr = run.traj
    in_side_lane = (tr.x > 9.5) & (tr.x < 11.5)
    assert np.all(np.abs(tr.y[in_side_lane] - 1.5) < 0.35)
    back = (tr.x > 19) & (tr.x < 23)
    assert np.all(np.abs(tr.y[back]) < 0.35)
    assert np.max(np.abs(tr.ay)) > 2.0  # it is a real manoeuvre


@pytest.mark.parametrize("name", manoeuvres.MANOEUVRES)
def test_every_manoeuvre_runs(name):
    run = drive(name, duration=4)
    assert np.all(np.isfinite(run.traj.r)) and len(run.stimulus.steer_us) > 0
    if name == "standstill":
        assert np.max(run.traj.vx) == 0 and len(run.stimulus.hall_t_us) == 0


def _steer_to_yaw_delay(run):
    tr = run.traj
    on = tr.t > run.cfg.plan.still + run.cfg.plan.run_up + 1
    x, y = tr.delta_cmd[on] - tr.delta_cmd[on].mean(), tr.r[on] - tr.r[on].mean()
    lags = np.arange(0, 200)
    xc = [np.dot(x[: len(x) - k], y[k:]) for k in lags]
    return lags[int(np.argmax(xc))] * 1e-3


def test_actuator_lag_delays_the_response():
    base = _steer_to_yaw_delay(drive("random_steer", duration=10))
    lagged = _steer_to_yaw_delay(drive("random_steer", ("actuator_lag",), duration=10))
    assert lagged - base == pytest.approx(CAR.tau_steer, abs=0.025)


def test_body_roll_scales_the_measured_ay_by_the_roll_gain():
    run = drive("steady_circle", ("body_roll",), duration=8, speed=3.0, speed_end=5.0, steer_amp=0.05)
    eff = vehicle.Effects({"body_roll"})
    ax, ay_meas, az, r = sensors.body_signals(run.traj, CAR, eff, 0.0)
    steady = run.traj.t > 10
    ratio = np.median(ay_meas[steady] / run.traj.ay[steady])
    assert ratio == pytest.approx(1 + vehicle.G * CAR.roll_gain, rel=0.01)


def test_accel_offset_adds_x_times_yaw_acceleration():
    run = drive("random_steer", ("accel_offset",), duration=5)
    ax, ay_meas, az, r = sensors.body_signals(run.traj, CAR, vehicle.Effects({"accel_offset"}), 0.0)
    assert np.allclose(ay_meas - run.traj.ay, CAR.x_acc * run.traj.r_dot)


def test_tyre_saturation_limits_lateral_acceleration():
    lin = drive("steady_circle", duration=10, speed=3.0, speed_end=8.0, steer_amp=0.12)
    sat = drive("steady_circle", ("tyre_saturation",), duration=10, speed=3.0, speed_end=8.0, steer_amp=0.12)
    assert np.max(np.abs(sat.traj.ay)) < CAR.mu * vehicle.G * 1.02
    assert np.max(np.abs(lin.traj.ay)) > np.max(np.abs(sat.traj.ay)) * 1.2


def test_relaxation_changes_transients_not_steady_state():
    kw = dict(duration=8, speed=3.0, speed_end=5.0, steer_amp=0.05)
    ss = drive("steady_circle", **kw).traj
    ss_relax = drive("steady_circle", ("tyre_relaxation",), **kw).traj
    late = ss.t > 10
    assert np.max(np.abs(ss.r[late] - ss_relax.r[late]) / np.abs(ss.r[late])) < 0.01
    fast = drive("chirp", duration=8, bandwidth=6.0).traj
    fast_relax = drive("chirp", ("tyre_relaxation",), duration=8, bandwidth=6.0).traj
    assert np.max(np.abs(fast.r - fast_relax.r)) > 0.05 * np.max(np.abs(fast.r))


def test_sensor_voltages_follow_the_datasheets():
    run = drive("standstill", duration=2)
    tg, volts = sensors.pin_voltages(run.traj, CAR, vehicle.Effects(set()), sensors.SensorParams(), 5000,
                                     np.random.default_rng(0), 0.0)
    assert np.mean(volts["ay"]) == pytest.approx(1.65, abs=0.002)  # zero g at Vs/2
    assert np.mean(volts["az"]) == pytest.approx(1.65 + 0.33, abs=0.002)  # +1 g at Vs/10 per g
    assert np.mean(volts["yaw"]) == pytest.approx(1.65, abs=0.002)
    noise_g = np.std(volts["ay"]) / 0.33
    # 150 ug/sqrt(Hz) through a first-order 50 Hz filter: sqrt(pi/2 * 50 Hz) * 150 ug ~ 1.3 mg
    assert noise_g == pytest.approx(150e-6 * math.sqrt(math.pi / 2 * 50), rel=0.2)
