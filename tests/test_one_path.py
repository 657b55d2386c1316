"""One set of numbers: `fit`, `compare`, each step of `diagnose` and `report` share one
fitting path, so the same model on the same data gives the same parameters and fit
percent in all four; and the noise floor is what a correct model reaches."""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest

from conftest import REPO, tool
from simdata import random_steer_pair
from stid.analysis.noise_floor import noise_floor_uncertainty
from stid.fit.dataset import Stretch
from stid.load import load_runs

M, A, B = 9.31, 0.2326, 0.2874
CF, CR, IZ = 400.0, 475.0, 0.25


def bicycle_run(vx_of_t, T=40.0, fs=100.0, seed=0, steer_rms_deg=3.0, bw=3.0, steer=None):
    """A linear single track written from its equations of motion, the steer held over each
    sample and the speed frozen within it: exact per-sample discretisation (matrix
    exponential), so the data are the physics to rounding. t, steer, ay, r, vx.
    ``steer``: the road-wheel angle to drive it with (default: band-limited random steer)."""
    from scipy.linalg import expm

    t = np.arange(int(T * fs)) / fs
    if steer is None:
        rng = np.random.default_rng(seed)
        spec = np.fft.rfft(rng.standard_normal(len(t)))
        spec[np.fft.rfftfreq(len(t), 1 / fs) > bw] = 0.0
        steer = np.fft.irfft(spec, len(t))
        steer *= np.radians(steer_rms_deg) / np.std(steer)
    vx = vx_of_t(t)
    x = np.zeros(2)
    ay, r = np.empty(len(t)), np.empty(len(t))
    E, v_of_E = None, None
    for i, (d, v) in enumerate(zip(steer, vx)):
        Am = np.array([[-(CF + CR) / (M * v), -(A * CF - B * CR) / (M * v) - v],
                       [-(A * CF - B * CR) / (IZ * v), -(A * A * CF + B * B * CR) / (IZ * v)]])
        Bm = np.array([CF / M, A * CF / IZ])
        if i == 0:
            x = -np.linalg.solve(Am, Bm * d)  # start in the steady state of the first steer
        ay[i] = (-(CF + CR) / v * x[0] - (A * CF - B * CR) / v * x[1] + CF * d) / M
        r[i] = x[1]
        if v != v_of_E:  # (one exponential for a constant speed)
            E, v_of_E = expm(np.block([[Am, Bm[:, None]], [np.zeros((1, 3))]]) / fs), v
        x = E[:2, :2] @ x + E[:2, 2] * d
    return {"t": t, "steer": steer, "ay": ay, "r": r, "vx": vx}


def swinging(t):
    """+-25% around 5 m/s: accelerating and braking every few seconds."""
    return 5.0 * (1 + 0.25 * np.sin(2 * np.pi * t / 7.0))

RC8 = str(REPO / "docs" / "examples" / "rc8.toml")


def _stretches_with_noise(vx_of_t, seeds, noise=0.02, fs=100.0):
    """Linear single-track runs written here from plain physics, with white sensor noise of a
    known size: the correct model's fit percent is the noise's, exactly."""
    out, true_fit = [], {}
    resid = {"ay": [], "r": []}
    clean = {"ay": [], "r": []}
    rng = np.random.default_rng(seeds[0] * 7)
    for s in seeds:
        run = bicycle_run(vx_of_t, T=40.0, fs=fs, seed=s)
        noisy = {}
        for o in ("ay", "r"):
            e = noise * np.std(run[o]) * rng.standard_normal(len(run["t"]))
            noisy[o] = run[o] + e
            keep = run["t"] >= 1.0  # the floor scores from its 1 s of memory on
            resid[o].append(e[keep])
            clean[o].append(noisy[o][keep])
        out.append(Stretch(f"run{s}", run["t"], run["steer"], noisy["ay"], noisy["r"], run["vx"],
                           float(np.median(run["vx"]))))
    for o in ("ay", "r"):
        e, y = np.concatenate(resid[o]), np.concatenate(clean[o])
        true_fit[o] = 100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean()))
    return out, true_fit


@pytest.mark.parametrize("profile", ["constant", "track"])
def test_the_true_model_does_not_beat_the_noise_floor(profile):
    """The floor estimates what a correct model reaches: within its stated uncertainty of
    the true model's fit, on data written here (constant 5 m/s, and +-25% swings)."""
    vx = (lambda t: np.full(len(t), 5.0)) if profile == "constant" else swinging
    st, true_fit = _stretches_with_noise(vx, (1, 2))
    floor, se = noise_floor_uncertainty(st)
    for o in ("ay", "r"):
        assert se[o] > 0
        # not beaten: the correct model is not above the floor beyond its uncertainty
        assert true_fit[o] <= floor[o] + 3 * se[o], (o, true_fit[o], floor[o], se[o])
        # and an estimate, not a bound far above: within a few of its standard errors
        assert floor[o] <= true_fit[o] + 3 * se[o] + 0.05, (o, true_fit[o], floor[o], se[o])


def test_fit_compare_diagnose_and_report_give_one_set_of_numbers(simdir, rc_vehicle, tmp_path):
    from stid.compare import compare
    from stid.diagnose import diagnose
    from stid.report import chain_of, write_report

    paths = random_steer_pair(simdir, ("actuator_lag",))
    runs = load_runs(paths, rc_vehicle)
    model = "bicycle+actuator_lag"
    r = subprocess.run([tool("stid"), "fit", *map(str, paths), "--vehicle", RC8, "--model", model, "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    fit_params = {n: v["value"] for n, v in doc["params"].items()}
    (entry,) = compare(runs, rc_vehicle, [model])
    rounds = diagnose(runs, rc_vehicle, "bicycle", peel=True)
    step = rounds[0].best
    assert step.effect == "actuator_lag"
    # diagnose's step carries its parameters with intervals
    js = step.to_json()
    lo, hi = js["intervals"]["tau_steer"]
    assert lo < js["params"]["tau_steer"] < hi
    report_res = dict(chain_of(rounds))[model]
    for name, value in fit_params.items():
        for where, got in (("compare", entry["params"][name]["value"]), ("diagnose", step.result.value(name)),
                           ("report", report_res.value(name))):
            assert got == pytest.approx(value, rel=2e-4), (name, where, got, value)
    for o in ("ay", "r"):
        for where, got in (("compare", entry["fit"][o]), ("diagnose", step.result.fit[o]),
                           ("report", report_res.fit[o])):
            assert round(got, 1) == round(doc["fit"][o], 1), (o, where, got, doc["fit"][o])
    # the page shows the same fit percent as `stid fit`
    page = write_report(runs, rc_vehicle, tmp_path / "rep", rounds=rounds).read_text()
    m = re.search(re.escape(model) + r": fit ay ([0-9.]+)%, r ([0-9.]+)%", page)
    assert m and float(m.group(1)) == round(doc["fit"]["ay"], 1) and float(m.group(2)) == round(doc["fit"]["r"], 1)
    # and the fitted model is not above the floor it is judged against, which `stid fit` gives
    # with its standard error as diagnose has it
    for o in ("ay", "r"):
        assert doc["fit"][o] <= rounds[0].floor[o] + 3 * rounds[0].floor_se[o]
        assert doc["noise_floor"][o] == round(rounds[0].floor[o], 2)
        assert doc["noise_floor_stderr"][o] == round(rounds[0].floor_se[o], 3)
