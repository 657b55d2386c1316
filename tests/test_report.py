"""stid report: one self-contained HTML page with the chain, the figures and the diagnosis."""

import base64
import re
import subprocess

from conftest import REPO, tool
from simdata import random_steer_pair


def test_report_is_self_contained_and_tells_the_story(simdir, tmp_path):
    paths = random_steer_pair(simdir, ("actuator_lag", "accel_offset"))
    r = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "rep")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    assert r.stdout.strip().endswith("report.html")
    images = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(images) >= 7  # runs, error fall, time, Bode, |ay| bins, residual correlations, residual spectra
    assert all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    assert "src='http" not in page and 'src="http' not in page  # nothing fetched from outside
    for text in ("bicycle+actuator_lag", "accel_offset", "N/rad", "noise floor", "The error falls",
                 "Residual spectra against the noise floor", "The logged runs", "95% interval"):
        assert text in page, text
    assert "white-space:pre-wrap" in page  # the diagnosis text wraps instead of scrolling
    # every model of the chain has its parameters on the page (with intervals)
    chain = re.findall(r"<h3>([^<:]+): fit ay", page)
    assert len(chain) == 3 and chain[0] == "bicycle" and chain[-1].count("+") == 2, chain
    # the command the page says to run next runs, from another directory too (it named the
    # vehicle by its name and the runs without their directories)
    import html
    import shlex

    nxt = shlex.split(html.unescape(re.search(r"next: ([^<\n]*)", page).group(1)))
    assert nxt[:2] == ["stid", "fit"] and nxt[-2:] == ["--model", chain[-1]], nxt
    again = subprocess.run([tool("stid"), *nxt[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr


def test_a_report_directory_that_cannot_be_made_is_named_before_any_work(simdir, tmp_path):
    paths = random_steer_pair(simdir, ("actuator_lag", "accel_offset"))
    (tmp_path / "a_file").write_text("")
    r = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "a_file" / "rep")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("stid report: error: cannot make the report directory") and "-o" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    f = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "a_file")],
                       capture_output=True, text=True, timeout=60)
    assert f.returncode == 2 and "is a file" in f.stderr and len(f.stderr.strip().splitlines()) == 1, f.stderr


# -- the page does not contradict itself (each of these failed on the first page's figures) --

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope="module")
def story(simdir):
    """The demo's story: servo lag and an accelerometer ahead of the CG, diagnosed once."""
    from stid.diagnose import diagnose
    from stid.load import load_runs
    from stid.report import chain_of
    from stid.vehicle_file import load_vehicle

    car = load_vehicle(REPO / "docs" / "examples" / "rc8.toml")
    runs = load_runs(random_steer_pair(simdir, ("actuator_lag", "accel_offset")), car)
    rounds = diagnose(runs, car, "bicycle", peel=True)
    return runs, car, rounds, chain_of(rounds)


def test_the_floor_and_the_residual_spectra_are_computed_the_same_way(story):
    from stid.analysis.noise_floor import floor_errors, floor_rate
    from stid.report import residual_spectra

    runs, car, rounds, chain = story
    stretches = rounds[-1].stretches
    f, spectra = residual_spectra(chain, stretches)
    df = f[1] - f[0]
    fl, _ = floor_errors(stretches)
    q = int(round(1 / (floor_rate(stretches) * stretches[0].dt)))
    for o in ("ay", "r"):
        # each spectrum's area is the variance of the very series the floor is scored on
        floor_var = np.var(np.concatenate(fl[o]))
        assert abs(spectra["floor"][o].sum() * df / floor_var - 1) < 0.1, o
        name, last = chain[-1]
        j = ("ay", "r").index(o)
        e = np.concatenate([(p.y - p.yhat)[::q, j][p.keep[::q] & ((p.t[::q] - p.t[0]) >= 1.0)]
                            for p in last.predictions])
        assert abs(spectra[name][o].sum() * df / np.var(e) - 1) < 0.1, o
        # the final model is at the floor: the two totals agree, as their fit percents do
        assert abs(spectra[name][o].sum() / spectra["floor"][o].sum() - 1) < 0.25, o


def test_the_measurement_stays_visible_under_the_models(story):
    from stid.report import time_figure

    fig = time_figure(story[3])
    ax = fig.axes[0]
    measured = [ln for ln in ax.get_lines() if ln.get_label() == "measured"]
    models = [ln for ln in ax.get_lines() if ln.get_label() != "measured"]
    assert len(measured) == 1 and models
    m = measured[0]
    # under every model, and wider than any: a model that fits runs inside it, and it still shows
    assert all(m.get_zorder() < ln.get_zorder() and m.get_linewidth() > 2 * ln.get_linewidth() for ln in models)


def test_a_correct_models_residual_is_judged_against_the_colour_of_the_chain(story):
    from stid.analysis.residuals import analyse, coloured_band, noise_autocorrelation

    runs, car, rounds, chain = story
    ra = analyse(chain[-1][1].predictions)
    L = len(ra.lags_s) // 2
    dt = float(ra.lags_s[1] - ra.lags_s[0])
    st = rounds[-1].stretches[0]
    # the gyro's residual (its noise is white before the chain): far outside the white band, as
    # the first report drew it; the chain's colour explains nearly all of its autocorrelation
    # (what is left, a few hundredths at some lags, is the simulated car's remaining model error)
    rho = noise_autocorrelation(runs[0].fs, dt, st.sensors["r"], max_lag_s=float(ra.lags_s[-1]))[:L + 1]
    auto = ra.auto["r"][1:]
    white_out = np.mean(np.abs(auto) > ra.band)
    coloured_out = np.mean(np.abs(auto - rho[1:]) > coloured_band(rho, ra.n))
    assert white_out > 0.1 and np.max(np.abs(auto)) > 0.5
    assert coloured_out < white_out / 2
    # (measured 0.18: the colour holds ~97% of the autocorrelation's energy; white noise, 0%)
    assert np.sqrt(np.mean((auto - rho[1:]) ** 2)) < 0.25 * np.sqrt(np.mean(auto ** 2))


def test_the_ay_bins_tell_a_friction_limit_from_a_lag():
    """Plain physics: a tyre that saturates (tanh) against a linear model that fits the small
    amplitudes overshoots at large |ay| (negative systematic part); against a response that is
    late it falls short at the peaks instead (positive)."""
    from stid.fit.result import Prediction
    from stid.report import ay_bins

    t = np.arange(0, 60, 0.005)
    rng = np.random.default_rng(0)
    drive = np.convolve(rng.standard_normal(len(t)), np.ones(80) / 80, mode="same") * 40
    linear = drive
    saturated = 7.0 * np.tanh(drive / 7.0)
    late = np.interp(t - 0.05, t, drive)
    keep = np.ones(len(t), bool)

    def bins(y, yhat):
        p = Prediction("x", t, drive, np.column_stack([y, y]), np.column_stack([yhat, yhat]), 4.0, keep)
        return {b[0]: b[3] for b in ay_bins([p])}

    sat = bins(saturated, linear)
    assert sat["> 6"] < -0.3 and abs(sat["0-2"]) < 0.05
    lag = bins(late, linear)  # late: the model's peak has passed where the measured one is: no overshoot
    assert all(v > 0 for v in lag.values()), lag


def test_the_page_opens_with_the_story_and_keeps_headings_with_their_figures(story, tmp_path):
    from stid.report import write_report

    runs, car, rounds, chain = story
    page = write_report(runs, car, tmp_path / "rep", rounds=rounds).read_text()
    assert page.index("The error falls") < page.index("<pre>")  # the figure first, the text dump last
    assert page.index("class='story'") < page.index("The error falls")
    assert "break-after:avoid" in page and "break-inside:avoid" in page
    # the bicycle's intervals are not read as an answer: it is far below the floor
    bicycle = page[page.index("<h3>bicycle:"):page.index("<h3>", page.index("<h3>bicycle:") + 5)]
    assert "its intervals hold only if it were right" in bicycle
