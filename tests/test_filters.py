"""stid.fit.filters computes scipy.signal's prefilter and decimation without importing
scipy.signal (half a second of every command): the same numbers, checked against
scipy.signal itself, and the import kept off the commands' path."""

import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from stid.fit import filters


@pytest.mark.parametrize("order,f_hz,fs", [(4, 20.0, 1000.0), (4, 20.0, 500.0), (2, 5.0, 200.0), (6, 30.0, 1000.0)])
def test_butterworth_sections_are_scipys(order, f_hz, fs):
    ours = filters.butter_lowpass_sos(order, f_hz, fs)
    theirs = signal.butter(order, f_hz, fs=fs, output="sos")
    assert np.allclose(ours, theirs, rtol=1e-12, atol=1e-15)


def test_a_cut_off_outside_the_band_is_refused():
    with pytest.raises(ValueError, match="half the sample rate"):
        filters.butter_lowpass_sos(4, 600.0, 1000.0)
    with pytest.raises(ValueError, match="even order"):
        filters.butter_lowpass_sos(3, 20.0, 1000.0)


@pytest.mark.parametrize("n", [16, 200, 40_000])
def test_zero_phase_filter_is_scipys(n):
    rng = np.random.default_rng(n)
    # a drifting signal with an offset: the edges (odd extension, steady-state start) matter
    x = np.cumsum(rng.standard_normal(n)) + 5.0
    sos = signal.butter(4, 20.0, fs=1000.0, output="sos")
    ours, theirs = filters.sosfiltfilt(sos, x), signal.sosfiltfilt(sos, x)
    assert np.max(np.abs(ours - theirs)) < 1e-12 * np.max(np.abs(theirs))
    # columns are filtered each on their own
    both = filters.sosfiltfilt(sos, np.column_stack([x, -2 * x]))
    assert np.allclose(both[:, 0], ours, rtol=0, atol=1e-12) and np.allclose(both[:, 1], -2 * ours, atol=1e-11)


def test_too_short_to_filter_is_refused():
    sos = filters.butter_lowpass_sos(4, 20.0, 1000.0)
    with pytest.raises(ValueError, match="too few"):
        filters.sosfiltfilt(sos, np.ones(15))


@pytest.mark.parametrize("q", [2, 4, 5, 6])
@pytest.mark.parametrize("n", [37, 1000, 40_001])
def test_decimation_is_scipys(q, n):
    x = np.sin(np.arange(n) * 0.01) + np.random.default_rng(q * n).standard_normal(n)
    ours, theirs = filters.decimate(x, q), signal.decimate(x, q, ftype="fir", zero_phase=True)
    assert ours.shape == theirs.shape
    assert np.max(np.abs(ours - theirs)) < 1e-12 * np.max(np.abs(theirs))


def test_the_filter_does_what_a_low_pass_does():
    """Plain physics, not scipy's word: a 2 Hz tone passes with its phase, 200 Hz is gone."""
    fs = 1000.0
    t = np.arange(20_000) / fs
    slow, fast = np.sin(2 * np.pi * 2.0 * t), np.sin(2 * np.pi * 200.0 * t)
    y = filters.sosfiltfilt(filters.butter_lowpass_sos(4, 20.0, fs), slow + fast)
    mid = slice(2000, -2000)
    assert np.max(np.abs(y[mid] - slow[mid])) < 1e-3  # zero phase: no lag on the tone
    d = filters.decimate(slow + fast, 5)
    assert np.max(np.abs(d[400:-400] - slow[::5][400:-400])) < 2e-3


def test_fit_and_diagnose_run_without_scipy_signal(tmp_path):
    """The reason the module exists: ``stid fit`` and ``stid diagnose`` on another logger's
    runs (single-track physics solved in the test) never import scipy.signal. The runs carry a
    servo trim, so that the diagnosis names it and weighs its evidence too (a Welch there had
    brought the import back, 0.6 s of every diagnosis that names something)."""
    from test_track_runs import A, B, M, bicycle_run, swinging, write_csv

    paths = []
    for seed in (1, 2):
        p = tmp_path / f"run{seed}.csv"
        write_csv(p, bicycle_run(swinging, T=12.0, seed=seed, trim=np.radians(1.5)))
        paths.append(str(p))
    veh = tmp_path / "car.toml"
    veh.write_text(f'name = "test car"\nmass = {M}\na = {A}\nb = {B}\n')
    for command in (["fit", "--method", "time"], ["diagnose"]):
        code = ("import sys\n"
                "sys.modules['scipy.signal'] = None  # importing it now fails, naming the importer\n"
                "from stid.cli import main\n"
                f"sys.exit(main({[command[0], *paths, '--vehicle', str(veh), *command[1:]]!r}))\n")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        assert "scipy.signal" not in out.stderr
    assert "steer_offset" in out.stdout and "NAMED" in out.stdout  # the evidence was weighed
