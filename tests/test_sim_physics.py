"""The simulated car obeys the textbook where it should, and each effect changes
what it should (checked against formulas written here, not against stid)."""

import math
import re

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


def test_steering_linkage_is_calibrated_at_small_angles_odd_and_degressive():
    """The four-bar linkage: slope 1 at straight ahead (the pulse calibration), each wheel's
    angle not odd on its own (inner and outer wheels differ) but the single track's mean odd
    (left and right are mirror images), and the short horn falling behind at large angles."""
    ratio = vehicle.linkage_ratio(CAR)
    f = lambda d: vehicle.road_wheel_angle(d, CAR, ratio)  # noqa: E731
    assert f(1e-4) == pytest.approx(1e-4, rel=1e-4)
    for d in (0.05, 0.15, 0.3):
        assert f(-d) == pytest.approx(-f(d), rel=1e-9)
    servo = 0.2 / ratio
    left, right = vehicle._wheel_angle(servo, 1, CAR), vehicle._wheel_angle(servo, -1, CAR)
    assert left > 0 and right > 0 and abs(left - right) > 1e-3  # the wheels toe differently in a turn
    assert f(0.2) < 0.2 * 0.97  # degressive by a few percent at 0.2 rad
    # a horn as long as the arm on a symmetric layout is nearly linear: the nonlinearity is geometry
    lin = vehicle.CarParams(steer_horn=0.02, steer_ackermann_deg=0.0)
    assert abs(vehicle.road_wheel_angle(0.2, lin, vehicle.linkage_ratio(lin)) / 0.2 - 1) < 0.01


def test_spool_moment_matches_the_small_slip_formula_and_opposes_yaw():
    """Mz = -(Cx t^2 / 4) r / vx for small slips with no drive force (Cx per axle)."""
    for vx, r in ((4.0, 0.5), (6.0, -0.8)):
        mz = vehicle.spool_moment(vx, r, 0.0, CAR)
        assert mz == pytest.approx(-CAR.Cx * CAR.track ** 2 / 4 * r / vx, rel=0.02)
        assert mz * r < 0


def test_locked_diff_damps_yaw_and_locks_the_rear_wheels():
    open_ = drive("step_steer", duration=6, speed=3.0, steer_amp=0.05)
    spool = drive("step_steer", ("locked_diff",), duration=6, speed=3.0, steer_amp=0.05)
    assert np.max(spool.traj.r) < 0.95 * np.max(open_.traj.r)  # extra understeer and yaw damping
    w = vehicle.wheel_speeds(spool.traj, CAR)
    moving = spool.traj.vx > 1.0
    assert np.array_equal(w[2][moving], w[3][moving])


def test_sensor_delay_shows_the_motion_of_delay_seconds_ago():
    run = drive("random_steer", duration=4)
    tg = np.arange(0, 8.0, 1e-3)
    now = sensors.body_signals(run.traj, CAR, vehicle.Effects(set()), 0.0, tg)
    late = sensors.body_signals(run.traj, CAR, vehicle.Effects({"sensor_delay"}), 0.0, tg)
    k = int(round(CAR.sensor_delay_s / 1e-3))
    for a, b in zip(now, late):
        assert np.allclose(b[k:], a[:-k], atol=1e-9 + 1e-6 * np.max(np.abs(a)))


def test_an_effect_file_adds_its_loads_and_signals(tmp_path):
    """A user's truth-side file: a yaw moment opposing yaw and a gyro that reads 10% high."""
    from hil_sim.effect_file import load_effect_file

    f = tmp_path / "damper.py"
    f.write_text("NAME = 'damper'\n"
                 "def body_loads(state, car):\n    return 0.0, -2.0 * state['r']\n"
                 "def sensor_signals(t, s, car):\n    s['r'] = 1.1 * s['r']\n    return s\n")
    eff = load_effect_file(f)
    plain = drive("step_steer", duration=6, speed=3.0, steer_amp=0.05)
    cfg = SimConfig(plan=Plan(name="step_steer", duration=6, speed=3.0, steer_amp=0.05), effect_files=(str(f),),
                    seed=1)
    damped = simulate_run(cfg)
    assert np.max(damped.traj.r) < 0.97 * np.max(plain.traj.r)
    tr = damped.traj
    _, _, _, r = sensors.body_signals(tr, CAR, vehicle.Effects(set(), (eff,)), 0.0)
    assert np.allclose(r, 1.1 * tr.r)


@pytest.mark.parametrize("text, says", [
    (None, "no such file"),
    ("def body_loads(:\n", "failed to load (SyntaxError"),
    ("x = 1\n", "defines none of steer_angle, body_loads, sensor_signals"),
    # results of the wrong shape, found when the simulator first calls the hook
    ("def body_loads(state, car):\n    return -2.0 * state['r']\n",
     "body_loads must return a pair (Fy [N], Mz [N m]); it returned float"),
    ("def sensor_signals(t, s, car):\n    s['r'] = 1.1 * s['r']\n",
     "sensor_signals must return the dict of signals it was given"),
    ("def steer_angle(delta, car):\n    pass\n", "steer_angle must return the road-wheel angle"),
    # an array of another length, written into the dict it was given and returned
    ("def sensor_signals(t, s, car):\n    s['r'] = s['r'][::2]\n    return s\n",
     "sensor_signals must return the dict of signals it was given"),
    # a nan, or a load that runs away (a trial user's: 'cannot convert float NaN to integer', or a run
    # written with its accelerometer at the ADC limit, naming nothing)
    ("def body_loads(state, car):\n    return float('nan') if state['vx'] > 0.5 else 0.0, 0.0\n",
     "body_loads returned nan or inf at vx = "),
    ("def sensor_signals(t, s, car):\n    s['ay'] = s['ay'] + float('inf')\n    return s\n",
     "sensor_signals returned nan or inf"),
    ("def body_loads(state, car):\n    return 1e4 * state['vy'], 1e4 * state['r']\n",
     "motion"),
])
def test_a_bad_effect_file_is_one_line_and_exit_2(tmp_path, text, says):
    import subprocess
    import sys

    f = tmp_path / "mine.py"
    if text is not None:
        f.write_text(text)
    r = subprocess.run([sys.executable, "-m", "hil_sim.cli", "--fast", "-o", str(tmp_path / "x.mcap"),
                        "--duration", "1", "--effect-file", str(f)], capture_output=True, text=True)
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args, says", [
    (["-o", "{tmp}/nodir/x.mcap"], "the directory {tmp}/nodir does not exist"),
    (["-o", "{tmp}/x.csv"], "-o writes an MCAP log, give a path ending in .mcap"),
    (["-o", "{tmp}/x.mcap", "--csv", "{tmp}/nodir/x.csv"], "--csv {tmp}/nodir/x.csv: the directory"),
    (["-o", "{tmp}/x.mcap", "--truth", "{tmp}/nodir/t.json"], "--truth {tmp}/nodir/t.json: the directory"),
])
def test_an_output_that_cannot_be_written_is_refused_before_the_run(tmp_path, args, says):
    """Found after the whole simulation, an unwritable path was a traceback, and left the
    files written before it (the .mcap of a failed --csv)."""
    import subprocess
    import sys

    args = [a.format(tmp=tmp_path) for a in args]
    r = subprocess.run([sys.executable, "-m", "hil_sim.cli", "--fast", "--duration", "1", *args],
                       capture_output=True, text=True)
    assert r.returncode == 2 and says.format(tmp=tmp_path) in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not list(tmp_path.iterdir()), r.stderr


@pytest.mark.parametrize("args, says", [
    (["--rate", "7"], "--rate 7: the firmware samples at 10 to 5000 Hz"),
    (["--rate", "0"], "--rate 0:"),
    (["--batch", "1000"], "--batch 1000: the firmware sends 1 to 38 samples per frame"),
    (["--batch", "30", "--wheel-speeds"], "--batch 30: the firmware sends 1 to 22 samples per frame"),
    (["--speed", "-5"], "--speed -5: a driving manoeuvre needs 1 to 30 m/s"),
    (["--steer-amp", "90"], "--steer-amp 90: give more than 0 and at most 30 degrees"),
    (["--ber", "2"], "--ber 2: a probability"),
    (["--bandwidth", "0"], "--bandwidth 0: give a positive frequency"),
    (["--still", "-1"], "--still -1: give 0 or more seconds"),
    (["--speed-swing", "0.3"], "--speed-swing is for --speed-profile track"),
    (["--disconnect-at", "2"], "--disconnect-at is for the served port"),
])
def test_a_value_the_car_or_its_firmware_cannot_take_is_refused_before_the_run(tmp_path, capsys, args, says):
    """They were accepted (a car at -5 m/s), a library's words (p < 0, p > 1 or p is NaN), or a
    traceback once the firmware refused them on the simulated board, leaving a partial .mcap.
    (In this process: stid-sim's main, as the command calls it.)"""
    from hil_sim.cli import main

    rc = main(["--fast", "--duration", "1", *args, "-o", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err
    assert rc == 2 and says in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and not list(tmp_path.iterdir()), err


@pytest.mark.parametrize("rate, batch, wheels, ok", [(7, 10, None, False), (5000, 10, None, True),
                                                     (500, 39, None, False), (500, 38, None, True),
                                                     (500, 23, 4, False), (500, 22, 4, True)])
def test_stid_sims_limits_are_the_firmwares(tmp_path, rate, batch, wheels, ok):
    """stid-sim refuses what the firmware would (the firmware's own check, on the simulated
    board, says it too: on stderr, not among its bytes, where it left a partial run)."""
    from hil_sim.cli import _check_options, build_parser
    from hil_sim.record import record
    from hil_sim.run import SimConfig

    args = build_parser().parse_args(["--fast", "--rate", str(rate), "--batch", str(batch), "--bandwidth", "2"]
                                     + (["--wheel-speeds"] if wheels else []))
    try:
        _check_options(args)
        refused = None
    except ValueError as e:
        refused = str(e)
    cfg = SimConfig(plan=Plan(name="random_steer", duration=0.2, still=0.0, bandwidth=2.0), rate_hz=rate,
                    batch=batch, wheel_speeds=bool(wheels))
    out = tmp_path / "x.mcap"
    if ok:
        assert refused is None
        record(cfg, out)
    else:
        assert refused is not None
        with pytest.raises(RuntimeError, match="ValueError: (rate_hz|batch) must be"):
            record(cfg, out)
        assert not out.exists()


def test_a_recorded_run_is_not_replaced_unasked(tmp_path):
    """stid-sim --fast -o onto an existing run replaced it (978 kB -> 294 kB, exit 0)."""
    import subprocess
    import sys

    out = tmp_path / "x.mcap"
    out.write_bytes(b"a run")
    cmd = [sys.executable, "-m", "hil_sim.cli", "--fast", "--duration", "1", "-o", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 2 and "exists: give another path, or --overwrite" in r.stderr, r.stderr
    assert out.read_bytes() == b"a run"
    r = subprocess.run(cmd + ["--overwrite"], capture_output=True, text=True)
    assert r.returncode == 0 and out.stat().st_size > 1000, r.stderr


def test_a_lossy_fast_run_says_what_the_link_lost(tmp_path):
    """--fast with link faults printed only the samples written, not what the faults took."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "hil_sim.cli", "--fast", "--duration", "1", "--ber", "1e-3",
                        "-o", str(tmp_path / "x.mcap")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    m = re.search(r"\((\d+) frames lost, (\d+) rejected, (\d+) samples missing on the faulty link\)", r.stderr)
    assert m and int(m.group(1)) > 0 and int(m.group(3)) > 0, r.stderr


def test_ctrl_c_while_the_simulator_loads_ends_it_without_a_traceback(monkeypatch, capsys):
    """The simulator loads scipy before it parses its options (about a second): Ctrl-C then
    printed Python's traceback, where Ctrl-C while it runs ends it with status 130."""
    import hil_sim.cli as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["--fast", "-o", "x.mcap"]) == 130
    assert capsys.readouterr().err == ""
