"""A value the samples cannot tell is left out, never written as a number: damaged logs and
lossy links export no value that differs from the undamaged run's by more than the
estimate's own error. (The review: after a damaged stretch or a burst of lost frames, the
first ~130 ms of the next piece exported vx = 0 while the car drove at 4 m/s.)"""

import subprocess

import numpy as np
import pytest

from conftest import tool
from host.errors import HostError
from host.units import wheel_speed
from stid.errors import InputError
from stid.export import write_csv
from stid.load import load_file
from test_files_damage import _damaged

CHANNELS = ("steer", "ay", "r", "vx", "ax")


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    """8 s at 4 m/s through the real firmware; the file flushed every second as stid-log does."""
    path = tmp_path_factory.mktemp("unknown") / "run.mcap"
    r = subprocess.run([tool("stid-sim"), "--fast", "-o", str(path), "--duration", "8", "--still", "0.5",
                        "--speed", "4", "--seed", "5"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return path


def _grid_keys(run, step):
    return np.round((run.t + run.meta["t0_mcu_s"]) / step).astype(np.int64)


class Reference:
    """The undamaged run, and each channel's own error where a damaged copy may legitimately
    differ: the gyro zero is a mean over the stand-still (its standard error), and a speed
    across lost samples is the mean over a longer hall interval (the speed's change there)."""

    def __init__(self, path):
        (self.run,) = load_file(path)
        self.step = 1 / self.run.fs
        self.rows = {k: i for i, k in enumerate(_grid_keys(self.run, self.step))}
        fs = self.run.fs
        still = self.run.vx < 0.05
        self.tol = {c: 1e-9 for c in CHANNELS}
        self.tol["r"] = 4 * float(np.std(self.run.r[still])) / np.sqrt(max(still.sum() / 10, 1))
        # the speed's own spread over +-0.25 s (several hall intervals at 4 m/s)
        w = int(0.25 * fs)
        v = self.run.vx
        self.vx_spread = np.array([np.ptp(v[max(0, i - w):i + w + 1]) for i in range(len(v))]) + 1e-9

    def check(self, runs, what):
        checked = 0
        for run in runs:
            rows = np.array([self.rows.get(k, -1) for k in _grid_keys(run, self.step)])
            valid = np.ones(len(run.t), bool) if run.valid is None else np.asarray(run.valid, bool)
            sel = valid & (rows >= 0)
            for c in CHANNELS:
                got, ref = getattr(run, c)[sel], getattr(self.run, c)[rows[sel]]
                tol = self.vx_spread[rows[sel]] if c == "vx" else self.tol[c]
                bad = np.abs(got - ref) > tol
                assert not bad.any(), (f"{what}, {run.name}: {c} differs by {np.abs(got - ref)[bad].max():.3g} "
                                       f"at t = {run.t[sel][bad][0]:.3f} s (allowed {np.atleast_1d(tol)[0]:.3g})")
            checked += int(sel.sum())
        return checked


def _damaged_copies(clean_run, tmp_path, n, seed):
    ref = Reference(clean_run)
    buf = clean_run.read_bytes()
    rng = np.random.default_rng(seed)
    bad = tmp_path / "bad.mcap"
    pieces = checked = 0
    for v in range(n):
        kind = ("flip", "flips", "zero_block", "bytes")[v % 4]
        bad.write_bytes(_damaged(buf, rng, kind))
        try:
            runs = load_file(bad)
        except (InputError, HostError):
            continue  # refused in one line: nothing exported
        pieces += len(runs) > 1
        checked += ref.check(runs, f"copy {v} ({kind})")
    return pieces, checked


def test_damaged_copies_export_no_value_they_cannot_tell(clean_run, tmp_path):
    pieces, checked = _damaged_copies(clean_run, tmp_path, 100, seed=1)
    assert pieces >= 10 and checked > 100_000  # the damage really cut runs into pieces


@pytest.mark.slow
def test_a_thousand_damaged_copies_export_no_value_they_cannot_tell(clean_run, tmp_path):
    pieces, checked = _damaged_copies(clean_run, tmp_path, 1000, seed=2)
    assert pieces >= 100


def test_a_lossy_link_exports_no_speed_of_zero_while_driving(clean_run, tmp_path):
    lossy = tmp_path / "lossy.mcap"
    r = subprocess.run([tool("stid-sim"), "--fast", "-o", str(lossy), "--duration", "8", "--still", "0.5",
                        "--speed", "4", "--seed", "5", "--ber", "3e-4"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    runs = load_file(lossy)
    assert len(runs) >= 3  # bursts of lost frames longer than 0.1 s cut the run
    Reference(clean_run).check(runs, "lossy link")
    # and the CSV: every row written is a row whose every value is known
    driving = [run for run in runs if run.meta["t0_mcu_s"] - runs[0].meta["t0_mcu_s"] > 3.0]
    assert len(driving) >= 2  # pieces that begin while the car drives at ~4 m/s
    for k, run in enumerate(driving):
        out = tmp_path / f"lossy{k}.csv"
        write_csv(run, out)
        data = np.genfromtxt(out, delimiter=",", names=True)
        assert np.isfinite(data["vx"]).all() and (data["vx"] > 2.0).all(), run.name


def test_the_speed_before_the_first_hall_interval_is_unknown_not_zero():
    """Plain physics: a wheel of 0.05 m radius, one magnet, rolling at 4 m/s; the samples start
    between edges (as after lost frames). Until an interval completes, the speed is NaN."""
    fs, v, radius = 500, 4.0, 0.05
    period_us = 2 * np.pi * radius / v * 1e6  # 78.5 ms per pulse
    t = np.arange(1000, 1_000_000, 1e6 / fs).astype(np.int64)
    edges = np.arange(-1, 20) * period_us + 1000 - 30_000  # the latest before the start is 30 ms old
    k = np.searchsorted(edges, t, side="right") - 1
    count, last = (k + 40) % 65536, edges[k].astype(np.int64)
    speed = wheel_speed(t, t % (1 << 30), count, last % (1 << 30), 1, radius)
    first_edge_in = np.searchsorted(t, edges[edges > t[0]][0])
    assert np.isnan(speed[:first_edge_in]).all()  # before the stretch's first new edge: unknown
    assert np.allclose(speed[first_edge_in:], v, rtol=1e-3)  # from it on: the interval [last before, it]
    # a wheel whose last edge was 5 s ago (a stand-still) is taken as standing, as before
    still = wheel_speed(t, t, np.full(len(t), 7), np.full(len(t), (-5_000_000) % (1 << 30)), 1, radius)
    assert (still == 0).all()


def test_export_to_stdout_and_into_a_pipe(clean_run, tmp_path):
    """`--csv -` is stdout; `--csv /dev/stdout` into a pipe waited for ever (the check that the
    output is not a recorded run read the pipe) and a terminal or pipe was refused as a file
    that exists. Neither writes a file named '-'."""
    stid = tool("stid")
    whole = tmp_path / "whole.csv"
    r = subprocess.run([stid, "export", str(clean_run), "--csv", str(whole)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    for target in ("-", "/dev/stdout"):
        r = subprocess.run(f"{stid} export {clean_run} --csv {target} | cat", shell=True, capture_output=True,
                           text=True, timeout=120, cwd=tmp_path)
        assert r.returncode == 0 and r.stdout == whole.read_text(), (target, r.stderr)
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "-").exists()


def test_export_never_writes_over_its_own_input(clean_run, tmp_path):
    """`stid export victim.csv --csv victim.csv --overwrite` turned a trial user's 1.1 MB logged CSV
    into its first 2.6 s (a CSV is a recorded run too); now refused, the file untouched."""
    stid = tool("stid")
    victim = tmp_path / "victim.csv"
    assert subprocess.run([stid, "export", str(clean_run), "--csv", str(victim)], capture_output=True,
                          timeout=120).returncode == 0
    before = victim.read_bytes()
    r = subprocess.run([stid, "export", str(victim), "--csv", str(victim), "--overwrite"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "never writes over its input" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert victim.read_bytes() == before
