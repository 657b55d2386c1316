"""Servo lag: the identifier against data written here from plain physics, and the
simulator's servo against the same physics.

The data: a linear single track (m, a, b, Cf, Cr, Iz of the reference car) whose road
wheel follows the servo command through a first-order lag, driven by a receiver's pulse
train (a command every ~20 ms, taken at each pulse's falling edge) and sampled at 500 Hz
through first-order sensor filters (ay 50 Hz, r 88 Hz), as the firmware samples. Between
events (samples, falling edges) the state is propagated exactly (matrix exponential with
the command held), so the data carry no integration error. The steer column is what the
loader makes of pulse-edge-timed steer: the staircase averaged over each sample period
centred on the sample (stid.convert.steer_at_servo_times).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg, signal

from stid.fit.fitting import fit
from stid.run import Run

M, A, B = 9.31, 0.2326, 0.2874  # the reference car (docs/examples/rc8.toml)
CF, CR, IZ = 400.0, 475.0, 0.25
TAU = 0.06  # s, servo time constant
FS = 500.0  # Hz, the firmware's sample rate
US_PER_RAD = 1145.9  # servo calibration (rc8.toml)
ACC_HZ, GYRO_HZ = 50.0, 88.0


def _matrices(vx: float, tau: float | None):
    """States vy, r, delta, ay_f, r_f (the last two: the sensor filters' outputs); input:
    the servo command. tau None: the wheel takes the command at once (no servo lag)."""
    a11, a12 = -(CF + CR) / (M * vx), -(CF * A - CR * B) / (M * vx) - vx
    a21, a22 = -(CF * A - CR * B) / (IZ * vx), -(CF * A * A + CR * B * B) / (IZ * vx)
    wa, wr = 2 * np.pi * ACC_HZ, 2 * np.pi * GYRO_HZ
    # ay = vy' + vx r = a11 vy + (a12 + vx) r + Cf / m delta
    Am = np.array([[a11, a12, CF / M, 0, 0],
                   [a21, a22, CF * A / IZ, 0, 0],
                   [0, 0, 0, 0, 0],
                   [wa * a11, wa * (a12 + vx), wa * CF / M, -wa, 0],
                   [0, wr, 0, 0, -wr]])
    if tau:
        Am[2, 2] = -1 / tau
        return Am, np.array([0, 0, 1 / tau, 0, 0.0])
    Bm = Am[:, 2].copy()  # delta is the command itself: its column drives the rest directly
    Am[:, 2] = 0.0
    Am[2, 2] = -1.0  # the unused delta state stays at rest
    Bm[2] = 0.0
    return Am, Bm


def _pulses(seed: int, duration: float, rms: float = 0.04, bw: float = 4.0):
    """(falling-edge times [s], commands [rad]): a receiver 300 ppm off 20 ms, its widths
    integer microseconds of a 4 Hz band-limited random steer."""
    rng = np.random.default_rng(seed)
    fs = 1000.0
    sos = signal.butter(4, bw, fs=fs, output="sos")
    w = signal.sosfiltfilt(sos, rng.standard_normal(int(duration * fs)))
    wish = rms * w / np.std(w)
    period = 0.02 * (1 + 300e-6)
    rise = 0.0031 + np.arange(int((duration - 0.0031) / period)) * period
    width_us = np.round(1500 + np.interp(rise, np.arange(len(wish)) / fs, wish) * US_PER_RAD)
    return rise + width_us * 1e-6, (width_us - 1500) / US_PER_RAD


def _propagate(Am, Bm, ts, fall, cmd):
    """The filtered outputs (ay_f, r_f) at the sample instants ``ts``, the command changing
    at ``fall``: exact between events."""
    ev = np.concatenate([ts, fall])
    which = np.concatenate([-np.ones(len(ts), int), np.arange(len(fall))])
    order = np.argsort(ev, kind="stable")
    Ainv = np.linalg.inv(Am)
    cache = {}
    x, u, now = np.zeros(5), 0.0, 0.0
    out, j = np.zeros((len(ts), 2)), 0
    for t, k in zip(ev[order], which[order]):
        h = t - now
        if h > 0:
            key = round(h * 1e10)
            if key not in cache:
                E = linalg.expm(Am * h)
                cache[key] = (E, Ainv @ (E - np.eye(5)) @ Bm)
            E, G = cache[key]
            x, now = E @ x + G * u, t
        if k < 0:
            out[j] = x[3], x[4]
            j += 1
        else:
            u = cmd[k]
    return out


def _steer_column(ts, fall, cmd):
    """The staircase's mean over each sample period centred on the sample (the loader's rule)."""
    f = np.concatenate([[-1.0], fall])
    c = np.concatenate([[0.0], cmd])
    cum = np.concatenate([[0.0], np.cumsum(c[:-1] * np.diff(f))])

    def integral(t):
        i = np.clip(np.searchsorted(f, t, side="right") - 1, 0, len(f) - 1)
        return cum[i] + c[i] * (t - f[i])

    h = 1 / FS
    return (integral(ts + h / 2) - integral(ts - h / 2)) / h


def plain_run(seed: int, vx: float, tau: float | None, duration: float = 24.0, noise=(0.0023, 0.0014)) -> Run:
    """A run as the firmware would log it; ``noise``: white noise [m/s^2, rad/s] on the
    samples (a tenth of the simulated car's, in the same ratio: sharp, and the output
    weights the fit chooses are those of real data)."""
    ts = np.arange(int(duration * FS)) / FS
    fall, cmd = _pulses(seed, duration)
    y = _propagate(*_matrices(vx, tau), ts, fall, cmd)
    rng = np.random.default_rng(seed + 7)
    y = y + np.asarray(noise) * rng.standard_normal(y.shape)
    return Run(name=f"plain_{seed}_{vx:g}", t=ts, steer=_steer_column(ts, fall, cmd), ay=y[:, 0], r=y[:, 1],
               vx=np.full(len(ts), vx),
               meta={"format": "csv", "sensor_chain": {"ay": ACC_HZ, "r": GYRO_HZ, "source": "test"}})


@pytest.mark.parametrize("tau,model", [(TAU, "bicycle+actuator_lag"), (None, "bicycle")])
def test_fit_is_unbiased_on_exact_single_track_data(rc_vehicle, tau, model):
    """Exact data of the model's own structure: what is left is the identifier's own error,
    which must stay within the noise (3 of the fit's own standard errors, ~0.02% for Iz)."""
    runs = [plain_run(1, 4.0, tau), plain_run(2, 6.0, tau)]
    res = fit(runs, rc_vehicle, model, "time", intervals="noise")
    truth = {"Cf": CF, "Cr": CR, "Iz": IZ, "tau_steer": TAU}
    z = {n: (res.value(n) - truth[n]) / se for n, se in zip(res.names, res.stderr)}
    assert all(abs(v) < 3.0 for v in z.values()), (z, res.table())


def test_simulated_servo_is_the_first_order_lag_of_the_pulse_staircase():
    """hil_sim's servo against the plain equation: the road-wheel angle obeys
    delta' = (cmd - delta) / tau with the command a staircase stepping at each falling
    edge, so the simulator's delta must equal the exact lag of the pulses it sent (its
    rate limit lies far beyond a 0.04 rad rms random steer)."""
    from hil_sim.manoeuvres import Plan, build
    from hil_sim.vehicle import CarParams, Effects, servo_rise_times_us, simulate

    car = CarParams()
    plan = Plan(name="random_steer", duration=8.0, speed=4.0, steer_amp=0.04)
    man = build(plan, 1e-3, np.random.default_rng(3))
    rise = servo_rise_times_us(car, float(man.t[-1]), np.random.default_rng(4))
    tr = simulate(car, Effects({"actuator_lag"}), man.t, man.delta_cmd, man.v_ref, pulse_rise_us=rise)
    fall = (tr.steer_rise_us + tr.steer_pulses_us) * 1e-6
    cmd = (tr.steer_pulses_us - car.steer_center_us) / car.steer_us_per_rad
    # delta(t) of the plain lag, exact between edges, at the simulator's rows
    a = -1.0 / car.tau_steer
    delta = np.empty(len(tr.t))
    d, u, now, k = float(tr.delta[0]), float(tr.delta_cmd[0]), 0.0, 0
    for i, t in enumerate(tr.t):
        while k < len(fall) and fall[k] <= t:
            d = u + (d - u) * np.exp(a * (fall[k] - now))
            now, u = fall[k], cmd[k]
            k += 1
        delta[i] = u + (d - u) * np.exp(a * (t - now))
    # RK4 at 1 ms on a 60 ms lag, split at every edge: exact to far below a microradian
    assert np.max(np.abs(tr.delta - delta)) < 1e-6, np.max(np.abs(tr.delta - delta))
    assert np.std(delta) > 0.02  # the steer did move
    rate = np.abs(np.diff(tr.delta) / np.diff(tr.t))
    assert rate.max() < 0.5 * car.steer_rate_max


def test_simulated_adc_reads_the_sensor_at_its_instant(tmp_path):
    """Through the whole chain (firmware on the simulated board, logger, MCAP), each ay
    count is the sensor's voltage at one instant: the count's error against the rows the
    board was given, interpolated at the sample's stamp, must not follow the voltage's
    slope (a slope-following error is a timing error: Iz moves ~5% per ms)."""
    from hil_sim.manoeuvres import Plan
    from hil_sim.record import record
    from hil_sim.run import SimConfig, simulate_run
    from host.mcap_read import read_log

    cfg = SimConfig(plan=Plan(name="random_steer", duration=8.0, speed=4.0, steer_amp=0.08), seed=3,
                    effects=("actuator_lag",))
    record(cfg, tmp_path / "run.mcap")
    st = simulate_run(cfg).stimulus  # the same rows the recording's board read (bit for bit)
    s = read_log(tmp_path / "run.mcap").samples
    t = s["t_mcu_us"].astype(float)
    moving = t > 3e6
    tg = np.arange(st.n_rows) / st.fs_sig * 1e6
    rows = np.round(st.volts[27] / 1e-4)  # ay on GP27, in the file's 0.1 mV
    counts = np.interp(t[moving], tg, rows) * 4095 / 33000  # ADC counts the voltage at the stamp is worth
    slope = np.interp(t[moving], tg, np.gradient(rows) * st.fs_sig * 1e-6) * 4095 / 33000  # counts per us
    err = s["ay"][moving] - counts
    shift = np.linalg.lstsq(np.column_stack([slope, np.ones_like(slope)]), err, rcond=None)[0][0]
    # ay is the scan's second channel (+2 us); the estimate's standard error here is ~4 us
    assert abs(shift) < 15.0, f"ay reads as if sampled {shift:+.1f} us from its stamp"
