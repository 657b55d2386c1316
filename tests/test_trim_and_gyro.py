"""A steering trim (steer_offset), a gyro scale error (gyro_scale) and sensor offsets
(sensor_bias), told apart.

Data written here from plain physics: the linear single track integrated by scipy from
its equations (not the project's simulator or its state-space code), started in its
steady state, with the effect added by hand where it acts on the car (the trim, at the
road wheel) or on the sensors (scale, offsets). A trim and a gyro offset leave the same
mean residual at one speed; the data's kinematics (ay = vy' + vx r) decide which.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, signal

from stid.fit.fitting import fit
from stid.load import load_runs

M, A, B = 9.31, 0.2326, 0.2874  # the reference car (docs/examples/rc8.toml)
CF, CR, IZ = 400.0, 475.0, 0.25
NOISE = (0.03, 0.003)  # m/s^2, rad/s rms


def plain_run(path, seed, speed, trim=0.0, k_gyro=0.0, bias_r=0.0, bias_ay=0.0, swing=0.0, duration=30.0,
              fs=200.0, rms=0.04):
    """Write a CSV (the import contract) of the linear single track driven by random steer at
    ``speed`` (swinging by ``swing`` in a 9 s sine): the road wheels at steer + ``trim``; the
    gyro reads (1 + ``k_gyro``) r + ``bias_r``, the accelerometer ay + ``bias_ay``.

    The equations, m (vy' + vx r) = Fyf + Fyr and Iz r' = a Fyf - b Fyr with linear tyres, are
    integrated by scipy (lsim at one speed, solve_ivp when it swings) from their steady state
    at the first instant; the steer is taken as the straight lines between its samples."""
    n = int(duration * fs)
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    w = signal.sosfiltfilt(signal.butter(4, 3.0, fs=fs, output="sos"), rng.standard_normal(n))
    steer = rms * w / np.std(w)
    vx = speed * (1.0 + swing * np.sin(2 * np.pi * t / 9.0))

    def matrices(v):
        """x' = F x + G delta for x = (vy, r), and ay = H x + K delta, at speed v."""
        front = CF * np.array([-1 / v, -A / v])  # Fyf = front . x + CF delta
        rear = CR * np.array([-1 / v, B / v])
        F = np.vstack([(front + rear) / M - np.array([0.0, v]), (A * front - B * rear) / IZ])
        G = np.array([CF / M, A * CF / IZ])
        return F, G, (front + rear) / M, CF / M

    road = steer + trim  # the wheels point trim off the command
    F0, G0, _, _ = matrices(vx[0])
    x0 = -np.linalg.solve(F0, G0 * road[0])
    if swing == 0.0:
        F, G, H, K = matrices(speed)
        _, _, x = signal.lsim((F, G[:, None], np.eye(2), np.zeros((2, 1))), road, t, X0=x0, interp=True)
    else:
        def rhs(tt, xx):
            k = min(int(tt * fs), n - 2)
            u = road[k] + (road[k + 1] - road[k]) * (tt * fs - k)
            Fv, Gv, _, _ = matrices(np.interp(tt, t, vx))
            return Fv @ xx + Gv * u

        x = integrate.solve_ivp(rhs, (t[0], t[-1]), x0, t_eval=t, max_step=4e-3, rtol=1e-8, atol=1e-10).y.T
    ay = np.array([matrices(v)[2] @ xi + CF / M * u for v, xi, u in zip(vx, x, road)])
    noise = np.random.default_rng(seed + 1000).standard_normal((2, n))
    ay_meas = ay + bias_ay + NOISE[0] * noise[0]
    r_meas = (1.0 + k_gyro) * x[:, 1] + bias_r + NOISE[1] * noise[1]
    np.savetxt(path, np.column_stack([t, steer, ay_meas, r_meas, vx]), delimiter=",",
               header="t,steer,ay,r,vx", comments="", fmt="%.9g")
    return path


def _runs(tmp_path, rc_vehicle, speeds=(4.0, 6.0), **kw):
    return load_runs([plain_run(tmp_path / f"run{k}.csv", k + 1, v, **kw) for k, v in enumerate(speeds)],
                     rc_vehicle)


def _inside(res, name, truth):
    lo, hi = dict(zip(res.names, res.ci95))[name]
    return lo <= truth <= hi


@pytest.mark.parametrize("model, truth", [
    ("bicycle+steer_offset", {"trim": -0.03}),
    ("bicycle+gyro_scale", {"k_gyro": 0.06}),
], ids=["steer_offset", "gyro_scale"])
def test_the_effect_is_recovered_from_plain_physics_within_its_interval(tmp_path, rc_vehicle, model, truth):
    """`stid fit`'s path on data the effect was written into by hand: its parameter and the car's
    come out inside their 95% intervals."""
    res = fit(_runs(tmp_path, rc_vehicle, **truth), rc_vehicle, model, "time")
    name, value = {"trim": "delta0", "k_gyro": "k_gyro"}[next(iter(truth))], next(iter(truth.values()))
    table = res.table()
    assert _inside(res, name, value), table
    for n, v in (("Cf", CF), ("Cr", CR), ("Iz", IZ)):
        assert _inside(res, n, v), table
    # and the interval says something: far narrower than the effect itself
    lo, hi = dict(zip(res.names, res.ci95))[name]
    assert hi - lo < 0.2 * abs(value), table
