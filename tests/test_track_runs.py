"""Identification on what a car brings back from a track: a speed that swings, a
link that loses frames, data from another logger. Every run here is written in
the test from plain physics (a linear single track integrated by scipy), not by
stid's models nor by the simulator."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from stid.models.model import Model
from stid.vehicle_file import Vehicle

M, A, B = 9.31, 0.2326, 0.2874
TRUE = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}
VEHICLE = Vehicle(name="test car", mass=M, a=A, b=B)


def bicycle_run(vx_of_t, T=40.0, fs=200.0, seed=0, steer_rms_deg=3.0, bw=3.0, still=0.0, geometry=False,
                trim=0.0):
    """A linear single track at the speed profile vx(t), integrated to 1e-10: t, steer, ay, r, vx.
    ``geometry``: the front force acts along the steered wheel (its lateral part is F cos(delta)),
    as on a real car: a nonlinearity that grows with the square of the steer. ``trim`` [rad]: the
    road wheels' angle at zero logged steer (a servo trim: delta = steer + trim)."""
    t = np.arange(int(T * fs)) / fs
    rng = np.random.default_rng(seed)
    sos = signal.butter(4, bw, fs=fs, output="sos")
    steer = signal.sosfiltfilt(sos, rng.standard_normal(len(t)))
    steer *= np.radians(steer_rms_deg) / np.std(steer)
    vx = vx_of_t(t)
    Cf, Cr, Iz = TRUE["Cf"], TRUE["Cr"], TRUE["Iz"]

    def forces(vy, r, d, v):
        return Cf * (d + trim - (vy + A * r) / v), Cr * (-(vy - B * r) / v)

    # between samples the steer is the smooth band-limited signal the samples were taken from
    # (a cubic spline through them), as a prefiltered log's is, not the chords between them
    steer_of_t = CubicSpline(t, steer)

    def f(tt, x):
        d, v = float(steer_of_t(tt)), np.interp(tt, t, vx)
        Ff, Fr = forces(x[0], x[1], d, v)
        if geometry:
            Ff = Ff * np.cos(d + trim)
        return [(Ff + Fr) / M - v * x[1], (A * Ff - B * Fr) / Iz]

    # start in the steady state of the first steer
    v0, d0 = vx[0], steer[0]
    K = np.array([[-(Cf + Cr) / (M * v0), -(A * Cf - B * Cr) / (M * v0) - v0],
                  [-(A * Cf - B * Cr) / (Iz * v0), -(A * A * Cf + B * B * Cr) / (Iz * v0)]])
    x0 = -np.linalg.solve(K, [Cf * (d0 + trim) / M, A * Cf * (d0 + trim) / Iz])
    sol = solve_ivp(f, (0, t[-1]), x0, t_eval=t, rtol=1e-10, atol=1e-12, max_step=1 / fs, method="DOP853")
    vy, r = sol.y
    Ff, Fr = forces(vy, r, steer, vx)
    if geometry:
        Ff = Ff * np.cos(steer + trim)
    return {"t": t, "steer": steer, "ay": (Ff + Fr) / M, "r": r, "vx": vx}


def swinging(t):
    """+-25% around 5 m/s: accelerating and braking every few seconds."""
    return 5.0 * (1 + 0.25 * np.sin(2 * np.pi * t / 7.0))


_LEAN_LOAD_SCRIPT = r"""
import json, numpy as np
from numba import njit
from stid.models import _ltv_numba as lpv
lpv.load_compiled()
ctx = lpv._ltv_run.targetctx
rng = np.random.default_rng(0)
L, n, m, ny, N = 5, 4, 1, 2, 400
F = 0.3 * rng.normal(size=(L, n, n)); G0 = rng.normal(size=(L, n, m)); G1 = rng.normal(size=(L, n, m))
C = rng.normal(size=(L, ny, n)); D = rng.normal(size=(L, ny, m)); off = rng.normal(size=(L, ny))
idx = rng.integers(0, L - 1, N).astype(np.int64); w = rng.random(N); u = rng.normal(size=(N, m))
args = (F, G0, G1, C, D, off, idx, w, idx, w, u, u, rng.normal(size=n))
compiled = lpv._ltv_run(*args)
plain = np.empty((N, ny))  # the recursion written out densely, matrices interpolated per sample
x = args[-1].copy()
for k in range(N):
    i, a = idx[k], w[k]
    lerp = lambda M: (1 - a) * M[i] + a * M[i + 1]
    plain[k] = lerp(C) @ x + lerp(D) @ u[k] + lerp(off)
    if k + 1 < N:
        x = lerp(F) @ x + lerp(G0) @ u[k] + lerp(G1) @ u[k + 1]

@njit
def later(x):  # numba compiles something new after the lean load: its own refresh must work
    return np.sum(np.sin(x)) + x.shape[0]

print(json.dumps({"diff": float(np.max(np.abs(compiled - plain))), "left": "refresh" in vars(ctx),
                  "later": float(later(np.ones(3))), "expect": float(np.sum(np.sin(np.ones(3))) + 3)}))
"""


def test_the_compiled_recursion_loads_without_the_whole_compiler_and_numba_still_compiles():
    """stid.models._ltv_numba.load_compiled (numba's build of the recursion) cuts numba's refresh before a cache lookup to the
    runtime's start: in a fresh process (twice: the first may compile and fill the cache,
    the second loads from it) the recursion equals the dense one written out here, the cut
    refresh is gone afterwards, and numba compiles a new function as usual."""
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _LEAN_LOAD_SCRIPT], capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, out.stderr
        got = json.loads(out.stdout)
        assert got["diff"] < 1e-12 and not got["left"], got
        assert got["later"] == pytest.approx(got["expect"], rel=1e-14)


def write_csv(path, cols):
    names = list(cols)
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for row in zip(*(cols[n] for n in names)):
            f.write(",".join(f"{x:.12g}" for x in row) + "\n")


def test_lpv_simulation_matches_an_ode_solver_at_a_swinging_speed():
    run = bicycle_run(swinging, T=30.0)
    y = Model("bicycle", VEHICLE).simulate(TRUE, run["steer"], 1 / 200.0, run["vx"])
    for j, out in enumerate(("ay", "r")):
        err = np.sqrt(np.mean((y[:, j] - run[out]) ** 2)) / np.std(run[out])
        assert err < 1e-4, (out, err)
    # the same call at one constant speed is the exact LTI filter
    const = np.full(len(run["t"]), 5.0)
    y1 = Model("bicycle", VEHICLE).simulate(TRUE, run["steer"], 1 / 200.0, const)
    y2 = Model("bicycle", VEHICLE).simulate(TRUE, run["steer"], 1 / 200.0, 5.0)
    assert np.allclose(y1, y2)



def test_a_stretch_simulates_the_same_whatever_was_simulated_before_it():
    """The discretisations at the speed lattice's nodes are shared by every stretch of an
    evaluation (stid.models.lpv._NodeFoh): a stretch simulated alone, after another at other
    speeds (which computed some of its nodes, and set the hint for the next), or again, gives
    the same numbers to round-off (the node matrices are the same numbers; the products that
    fill the grid from them may add in another order), and still the ODE solver's."""
    from stid.models import lpv

    slow = bicycle_run(lambda t: 3.0 * (1 + 0.2 * np.sin(2 * np.pi * t / 5.0)), T=15.0, seed=1)
    fast = bicycle_run(swinging, T=15.0, seed=2)
    model = Model("bicycle", VEHICLE)

    def sim(run):
        return model.simulate(TRUE, run["steer"], 1 / 200.0, run["vx"])

    lpv._NODE_FOH.clear()
    model._laws.clear()
    alone = sim(fast)
    lpv._NODE_FOH.clear()
    model._laws.clear()
    sim(slow)
    after = sim(fast)
    again = sim(fast)
    scale = np.abs(alone).max(axis=0)
    assert np.all(np.abs(after - alone).max(axis=0) <= 1e-12 * scale)
    assert np.all(np.abs(again - alone).max(axis=0) <= 1e-12 * scale)
    for j, out in enumerate(("ay", "r")):
        assert np.sqrt(np.mean((after[:, j] - fast[out]) ** 2)) / np.std(fast[out]) < 1e-4


def test_a_jacobians_columns_simulated_in_one_batch_are_each_column_alone():
    """A forward-difference Jacobian simulates as many parameter sets as the model has parameters,
    each a little apart; Model.simulate_many discretises them in one batch. The numbers must be
    those each set gives alone (a column is a difference over a relative step of 1.5e-8: a
    round-off apart in one of the two would show in it), on the models the batch takes (a servo
    run apart ahead of a linkage map; a sensor's place, which moves no state matrix) and on one it
    hands back to one by one (a user's effect with another speed law than the single track's)."""
    from stid.models import lpv
    from stid.models.effect import Effect
    from stid.models.params import Param

    class SpeedSquared(Effect):  # (not registered: only this model has it)
        name = "speed_squared_test"
        stage = "output"
        params = (Param("k_v2", "s", "a yaw-rate gain that grows with the square of the speed", 0.01, 0.0, 1.0),)

        def apply(self, sys, p, ctx):
            sys = sys.copy()
            sys.add_to_output("r", state=sys.states[1], gain=p["k_v2"] * ctx.vx ** 2 * 1e-3)
            return sys

    run = bicycle_run(swinging, T=12.0, seed=3)
    cases = [Model("bicycle", VEHICLE), Model("bicycle+actuator_lag+steering_nonlinearity", VEHICLE),
             Model("bicycle+body_roll+accel_offset", VEHICLE)]
    custom = Model("bicycle", VEHICLE)
    custom.effects.append(SpeedSquared())
    custom._ordered.append(custom.effects[-1])
    custom.params.append(SpeedSquared.params[0])
    custom._law_known = False
    for model in cases + [custom]:
        p = model.defaults()
        p.update({k: v for k, v in TRUE.items() if k in p})
        ps = [p] + [{**p, n: p[n] + 1.5e-8 * max(abs(p[n]), 1.0)} for n in model.param_names]
        lpv._NODE_FOH.clear()
        model._laws.clear()
        alone = [model.simulate(q, run["steer"], 1 / 200.0, run["vx"]) for q in ps]
        lpv._NODE_FOH.clear()
        model._laws.clear()
        batch = model.simulate_many(ps, run["steer"], 1 / 200.0, run["vx"])
        scale = np.abs(alone[0]).max(axis=0)
        for q, a, b in zip(ps, alone, batch):
            assert np.all(np.abs(a - b).max(axis=0) <= 1e-13 * scale), (model.name, q)
        for n, a, b in zip(model.param_names, alone[1:], batch[1:]):  # the Jacobian's columns
            ja, jb = a - alone[0], b - batch[0]
            assert np.linalg.norm(jb - ja) <= 1e-5 * np.linalg.norm(ja) + 1e-15 * np.linalg.norm(alone[0]), \
                (model.name, n)
    assert not custom._law(custom.defaults(), ["ay", "r"], ["delta"], None, False).ok  # it did take the other path


def test_a_stack_of_discretisations_with_one_defective_system_gives_each_its_own():
    """The batched first-order hold takes each system in its eigenbasis, and one whose eigenvector
    matrix cannot be inverted by the matrix exponential. One such system in a stack (a Jacobian's
    batch) had sent every other one to the exponential too (numpy inverts a stack at once, and
    fails it whole): each is to keep its own way, and its own numbers to round-off."""
    from stid.models.lpv import _batched_foh

    rng = np.random.default_rng(0)
    A = -np.eye(2)[None] * rng.uniform(1, 20, (6, 1, 1)) + rng.normal(0, 3, (6, 2, 2))
    A[3] = [[-5.0, 1.0], [0.0, -5.0]]  # defective (a repeated pole)
    A[4] = [[0.0, 0.0], [0.0, 0.0]]  # poles at zero: the exponential's case too
    B = rng.normal(0, 1, (6, 2, 1))
    eig = np.linalg.eig

    def eig_singular_at_3(M):  # the eigenvectors of system 3 exactly parallel, as numpy may give them
        lam, V = eig(M)
        if len(M) == 6:
            V[3] = [[1.0, 1.0], [0.0, 0.0]]
        elif np.array_equal(M[0], A[3]):
            V[0] = [[1.0, 1.0], [0.0, 0.0]]
        return lam, V

    np.linalg.eig = eig_singular_at_3
    try:
        stacked = _batched_foh(A, B, 0.005)
        alone = [_batched_foh(A[i:i + 1], B[i:i + 1], 0.005) for i in range(6)]
    finally:
        np.linalg.eig = eig
    for i in range(6):  # (sent to the exponential, the others were 5e-14 to 2e-13 of their size off)
        for s, a in zip(stacked, alone[i]):
            assert np.max(np.abs(s[i] - a[0])) <= 1e-15 * np.max(np.abs(a[0])), i
    # and the exponential is right for the defective one: F = e^{A dt}
    from scipy.linalg import expm
    assert np.allclose(stacked[0][3], expm(A[3] * 0.005), rtol=1e-12)


@pytest.mark.parametrize("fs, target, q", [(500.0, 200.0, 3), (500.0 * (1 + 1e-13), 200.0, 3),
                                           (500.0 * (1 - 1e-13), 200.0, 3), (400.0, 200.0, 2),
                                           (1000.0, 200.0, 5), (300.0, 200.0, 1), (200.0, 200.0, 1),
                                           (460.0, 200.0, 2), (480.0, 200.0, 2), (495.0, 200.0, 3)])
def test_the_decimation_factor_is_the_nearest_rate_and_does_not_flip_with_rounding(fs, target, q):
    """A 500 Hz log for the fit's 200 Hz: 167 Hz (q=3) is nearer as a ratio than 250 Hz, and
    the choice must not depend on the last bit of the log's median sample interval (it did:
    round(2.5) went either way)."""
    from stid.fit.dataset import decimation

    assert decimation(fs, target) == q
    if q > 1:  # nearest as a ratio among the neighbours
        assert abs(np.log(fs / q / target)) <= min(abs(np.log(fs / (q + d) / target)) for d in (-1, 1) if q + d >= 1)

def test_noise_free_csv_at_a_swinging_speed_is_fitted_exactly(tmp_path):
    """Another logger's clean linear data, no sensor filter declared: fit >= 99.9%,
    parameters within 0.1% (issue: the model used to filter every source at 50/88 Hz)."""
    paths = []
    for seed in (1, 2):
        run = bicycle_run(swinging, seed=seed)
        p = tmp_path / f"track{seed}.csv"
        write_csv(p, run)
        paths.append(str(p))
    veh = tmp_path / "car.toml"
    veh.write_text(f'name = "test car"\nmass = {M}\na = {A}\nb = {B}\n')
    out = subprocess.run([sys.executable, "-m", "stid.cli", "fit", *paths, "--vehicle", str(veh),
                          "--model", "bicycle", "--method", "time", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["fit"]["ay"] >= 99.9 and res["fit"]["r"] >= 99.9, res["fit"]
    for k, v in TRUE.items():
        assert abs(res["params"][k]["value"] / v - 1) < 1e-3, (k, res["params"][k]["value"])
    # it says once which chain it assumed: none, for a CSV without [sensors]
    assert sum("sensor chain" in n for n in res["notes"]) == 1
    assert "unfiltered" in " ".join(res["notes"])


def test_a_declared_sensor_chain_is_applied(tmp_path):
    """The same data passed through a 30 Hz first-order filter on ay, declared in the vehicle
    file: the fit is exact again; undeclared, it is not."""
    run = bicycle_run(swinging, seed=3)
    fs = 200.0
    w = 2 * np.pi * 30.0
    b, a = signal.bilinear([w], [1, w], fs)  # close to first-order at 30 Hz for this band
    zi = signal.lfilter_zi(b, a) * run["ay"][0]
    run["ay"] = signal.lfilter(b, a, run["ay"], zi=zi)[0]
    p = tmp_path / "f.csv"
    write_csv(p, run)
    from stid.fit.fitting import fit
    from stid.load import load_runs
    declared = Vehicle(name="x", mass=M, a=A, b=B, sensors={"accel_bandwidth_hz": 30.0})
    good = fit(load_runs([p], declared), declared, "bicycle", "time")
    bad = fit(load_runs([p], VEHICLE), VEHICLE, "bicycle", "time")
    assert good.fit["ay"] > 99.5
    assert abs(good.value("Iz") / 0.25 - 1) < 0.01
    assert abs(bad.value("Iz") / 0.25 - 1) > 2 * abs(good.value("Iz") / 0.25 - 1)


def _staircase_case(period_us, fs=500, T=20.0, seed=0, offset_us=1234):
    """A receiver's pulse train (command = a smooth random steer) sampled by a sampler at fs:
    what a v2 log holds. Returns the sample arrays and a function giving the staircase's
    exact mean over [a, b] (us)."""
    rng = np.random.default_rng(seed)
    h = int(1e6 / fs)
    t_s = np.arange(int(T * fs)) * h + offset_us  # sample instants [us]
    n_p = int(T * 1e6 / period_us) + 2
    rise = 777 + np.arange(n_p) * period_us + rng.integers(-3, 4, n_p)  # a little jitter
    tt = np.linspace(0, T + 1, 4000)
    cmd = np.interp(rise * 1e-6, tt, np.convolve(rng.standard_normal(4000), np.ones(60) / 60, "same"))
    width = np.round(1500 + 400 * cmd / np.max(np.abs(cmd))).astype(np.int64)
    fall = rise + width
    j = np.searchsorted(fall, t_s, side="right") - 1
    ok = j >= 0
    t_s, j = t_s[ok], j[ok]
    steer_us, steer_t = width[j], fall[j]
    veh = Vehicle(name="x", mass=M, a=A, b=B)
    c = (width - veh.steer_center_us) / veh.steer_us_per_rad

    def mean(a, b):  # exact mean of the staircase over [a, b]
        grid = np.arange(a, b) + 0.5
        k = np.clip(np.searchsorted(fall, grid, side="right") - 1, 0, None)
        return float(np.mean(c[k]))
    return t_s, steer_us, steer_t, veh, mean, h


def _delay_us(x, ref, fs):
    """Least-squares delay of x against ref (both low-passed alike) [us]."""
    sos = signal.butter(4, 20, fs=fs, output="sos")
    xl, rl = signal.sosfiltfilt(sos, x), signal.sosfiltfilt(sos, ref)
    d = np.gradient(rl) * fs
    return float(-np.dot(xl - rl, d) / np.dot(d, d)) * 1e6


@pytest.mark.parametrize("period_us,offset_us", [(20000, 1234), (20000, 334), (19987, 1234)])
def test_steer_is_rebuilt_at_the_servo_pulse_edges(period_us, offset_us):
    """Phase-locked to 500 Hz sampling at two phases, and free-running: the rebuilt steer is
    the staircase's exact mean over each sample period, with no delay."""
    rebuilt, _ = _delays(period_us, offset_us)
    assert abs(rebuilt) < 5


def _delays(period_us, offset_us):
    from stid.convert import steer_at_servo_times

    t_s, steer_us, steer_t, veh, mean, h = _staircase_case(period_us, offset_us=offset_us)
    mod = 1 << 30
    steer, timed = steer_at_servo_times(t_s, t_s % mod, steer_us, steer_t % mod, veh, mod, t_s, h)
    assert timed
    exact = np.array([mean(t - h // 2, t + h // 2) for t in t_s[100:-100]])
    assert np.max(np.abs(steer[100:-100] - exact)) < 1e-9
    fs = 1e6 / h
    ref = np.array([mean(t - h // 2, t + h // 2) for t in t_s])
    sampled = (steer_us - veh.steer_center_us) / veh.steer_us_per_rad
    return _delay_us(steer, ref, fs), _delay_us(sampled, ref, fs)


def test_steer_sampled_at_the_sample_instant_is_off_by_the_phase():
    """What v1 logs do: the error depends on where the pulses fall between samples."""
    delays = [_delays(20000, off)[1] for off in (1234, 334, 1834)]
    assert np.ptp(delays) > 300  # us: a fixed, phase-dependent timing error when phase-locked


def test_a_receiver_faster_than_the_sampler_is_rebuilt_without_delay(monkeypatch):
    """A surface receiver's 333 Hz frames sampled at 100 Hz: each record holds only the latest
    pulse, so 3 in 10 pulses are logged. Held from one logged pulse to the next, the staircase
    was ~3.6 ms late (what put a 1:10 car's sigma_f 44% low); with the receiver's period found
    from the logged pulses' rising edges, the pulses between are put back and their commands
    interpolated: no delay left, and the loader says what the log lacks."""
    from stid import convert
    from stid.load import fast_receiver_warning

    mod = 1 << 30
    t_s, steer_us, steer_t, veh, mean, h = _staircase_case(3001, fs=100, offset_us=334)
    fall, width = convert.logged_pulses(t_s, t_s % mod, steer_us, steer_t % mod, mod)
    period = convert.receiver_period_us(fall - width)
    assert abs(period - 3001) < 1
    assert 0.28 < convert.pulses_in_log(fall - width, period) < 0.32
    ref = np.array([mean(t - h // 2, t + h // 2) for t in t_s])
    steer, timed = convert.steer_at_servo_times(t_s, t_s % mod, steer_us, steer_t % mod, veh, mod, t_s, h)
    assert abs(_delay_us(steer, ref, 100.0)) < 200
    with monkeypatch.context() as m:  # the loader before: the median gap (3 frames) as the period
        m.setattr(convert, "receiver_period_us", lambda rise: None)
        held, _ = convert.steer_at_servo_times(t_s, t_s % mod, steer_us, steer_t % mod, veh, mod, t_s, h)
    assert _delay_us(held, ref, 100.0) > 3000
    note = fast_receiver_warning(fall - width, 100.0)
    assert "every 3.0 ms (333 Hz)" in note and "30% of them" in note and "400 Hz" in note
    # sampled at 500 Hz every pulse is in the log: nothing to say
    t_s, steer_us, steer_t, veh, mean, h = _staircase_case(3001, fs=500, offset_us=334)
    fall, width = convert.logged_pulses(t_s, t_s % mod, steer_us, steer_t % mod, mod)
    assert convert.pulses_in_log(fall - width, convert.receiver_period_us(fall - width)) == 1.0
    assert fast_receiver_warning(fall - width, 500.0) is None


def test_missing_rows_are_gaps_not_data(tmp_path):
    """A CSV from a lossy logger: rows missing in blocks. The fit leaves them out (and the
    prefilter's reach around them), and lands where the complete log lands."""
    from stid.fit.fitting import fit
    from stid.load import load_runs

    run = bicycle_run(swinging, seed=5)
    rng = np.random.default_rng(7)
    n = len(run["t"])
    noisy = dict(run, ay=run["ay"] + 0.1 * rng.standard_normal(n), r=run["r"] + 0.01 * rng.standard_normal(n))
    keep = np.ones(n, bool)
    for s in range(0, n, 4):  # 20 ms blocks at 200 Hz, 17% lost, as BER 1e-4 loses frames
        if rng.random() < 0.17:
            keep[s:s + 4] = False
    full, lossy = tmp_path / "full.csv", tmp_path / "lossy.csv"
    write_csv(full, noisy)
    write_csv(lossy, {k: v[keep] for k, v in noisy.items()})
    runs = load_runs([lossy], VEHICLE)
    assert runs[0].valid is not None and abs((~runs[0].valid).mean() - (~keep).mean()) < 0.01
    a = fit(load_runs([full], VEHICLE), VEHICLE, "bicycle", "time")
    b = fit(runs, VEHICLE, "bicycle", "time")
    assert any("out of the cost" in n for n in b.notes), b.notes
    for k in TRUE:
        assert abs(b.value(k) / a.value(k) - 1) < 0.02, (k, a.value(k), b.value(k))
        lo, hi = b.ci95[b.names.index(k)]
        assert lo < TRUE[k] < hi or abs(b.value(k) / TRUE[k] - 1) < 0.01


# -- on the simulated car (its truth was written apart from stid's models) ------------

RC8 = "docs/examples/rc8.toml"
TRUTH_SIM = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}


def _sim(path, *args):
    out = subprocess.run([sys.executable, "-m", "hil_sim.cli", "--fast", "-o", str(path), *args],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return str(path)


def _fit_json(paths, model="bicycle"):
    out = subprocess.run([sys.executable, "-m", "stid.cli", "fit", *paths, "--vehicle", RC8, "--model", model,
                          "--json"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout), out.stderr


@pytest.fixture(scope="module")
def lossy_pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("lossy")
    runs = {}
    for kind, extra in (("clean", []), ("ber", ["--ber", "1e-4"])):
        runs[kind] = [_sim(d / f"{kind}{s}.mcap", "--duration", "40", "--seed", str(s), "--speed", str(v), *extra)
                      for s, v in ((21, 4), (22, 6))]
    return runs


def test_a_lossy_link_gives_the_clean_link_numbers(lossy_pair):
    """BER 1e-4 loses ~17-20% of the frames; lost samples are gaps, never data."""
    clean, _ = _fit_json(lossy_pair["clean"])
    lossy, err = _fit_json(lossy_pair["ber"])
    assert "lost on the link" in err
    for k in TRUTH_SIM:
        a, b = clean["params"][k]["value"], lossy["params"][k]["value"]
        assert abs(b / a - 1) < 0.02, (k, a, b)


def test_a_track_run_with_a_swinging_speed_is_fitted(tmp_path):
    """The speed moves +-25% every 2-5 s: no constant-speed stretch, and the fit follows it."""
    paths = [_sim(tmp_path / f"track{s}.mcap", "--duration", "40", "--seed", str(s), "--speed", str(v),
                  "--speed-profile", "track") for s, v in ((31, 4), (32, 6))]
    from stid.load import load_runs
    from stid.vehicle_file import load_vehicle
    from stid import segments

    for r in load_runs(paths, load_vehicle(RC8)):
        moving = r.vx > 1.0
        assert np.ptp(r.vx[moving][int(3 * r.fs):]) > 0.3 * np.median(r.vx[moving])  # it really swings
        assert not segments.constant_speed(r.vx, r.fs, min_s=12.0)
    res, _ = _fit_json(paths)
    for k, v in TRUTH_SIM.items():
        assert abs(res["params"][k]["value"] / v - 1) < 0.03, (k, res["params"][k])
    assert res["fit"]["ay"] > 97 and res["fit"]["r"] > 97


def test_large_angle_geometry_in_the_data_widens_the_intervals_to_the_truth():
    """A car with the front force along the steered wheel (cos delta), fitted by the linear
    single track at 6 deg rms of steer: noise-only intervals exclude the truth; the printed
    ones say the data show the geometry, and hold the truth. The same car without that
    geometry (an exact linear bicycle) is not widened."""
    from stid.fit.fitting import fit
    from stid.run import Run

    def runs(geometry):
        out = []
        for seed in (41, 42):
            d = bicycle_run(swinging, T=25.0, seed=seed, steer_rms_deg=6.0, geometry=geometry)
            rng = np.random.default_rng(seed + 100)
            n = len(d["t"])
            out.append(Run(f"g{seed}", d["t"], d["steer"], d["ay"] + 0.05 * rng.standard_normal(n),
                           d["r"] + 0.005 * rng.standard_normal(n), d["vx"]))
        return out

    car = runs(True)  # (integrated once: each run is 25 s at 1e-10, most of this test's time)
    geo = fit(car, VEHICLE, "bicycle", "time")
    noise_only = fit(car, VEHICLE, "bicycle", "time", intervals="noise")
    assert "large-angle geometry" in geo.interval
    i = geo.names.index("Cf")
    lo, hi = noise_only.ci95[i]
    assert not lo < TRUE["Cf"] < hi  # the model error is real, and noise-only intervals miss it
    for k, v in TRUE.items():
        lo2, hi2 = geo.ci95[geo.names.index(k)]
        assert lo2 < v < hi2, (k, lo2, hi2)
    plain = fit(runs(False), VEHICLE, "bicycle", "time")
    assert "large-angle geometry" not in plain.interval



def test_a_trimmed_cars_geometry_is_worked_out_at_its_road_wheel_angle():
    """A car with the front force along the steered wheel and a servo trim of 1.4 deg (the
    wheel at steer + trim), with the gyro's and accelerometer's offsets, at 4 and 6 m/s, fitted
    with the trim and the offsets: the geometry is the only model error, so the answer with
    exact geometry (the estimate plus its allowance) is the truth within its noise (2 noise-only
    se: 399.85 +- 0.30), and every interval holds the truth. Worked out at the logged command's
    angle, as it was, the geometry's answer fell 0.17% short (399.34: 2.2 se)."""
    from stid.fit.fitting import fit
    from stid.run import Run

    trim, bias_r, bias_ay = 0.025, 0.03, 0.25
    runs = []
    for seed, speed in ((43, 4.0), (44, 6.0)):
        d = bicycle_run(lambda t, v=speed: np.full_like(t, v), T=25.0, seed=seed, geometry=True, trim=trim)
        rng = np.random.default_rng(seed + 100)
        n = len(d["t"])
        runs.append(Run(f"t{seed}", d["t"], d["steer"], d["ay"] + bias_ay + 0.05 * rng.standard_normal(n),
                        d["r"] + bias_r + 0.005 * rng.standard_normal(n), d["vx"]))
    res = fit(runs, VEHICLE, "bicycle+sensor_bias+steer_offset", "time")
    se = fit(runs, VEHICLE, "bicycle+sensor_bias+steer_offset", "time", intervals="noise").stderr
    i = res.names.index("Cf")
    exact = res.all_params()["Cf"] + res.ci_allowance[i]  # (cos delta lowers the force: the step is up)
    assert abs(exact - TRUE["Cf"]) < 2 * se[i], (exact, se[i])
    truth = dict(TRUE, delta0=trim, bias_r=bias_r, bias_ay=bias_ay)
    for k, v in truth.items():
        lo, hi = res.ci95[res.names.index(k)]
        assert lo < v < hi, (k, lo, hi, res.interval)
