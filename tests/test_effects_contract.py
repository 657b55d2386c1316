"""Contract tests over every registered effect (a new effect is tested the moment it
is registered), and a user-defined effect written as docs/writing_an_effect.md shows."""

import re

import numpy as np
import pytest

from conftest import REPO
from stid.models.effect import available_effects, unregister_effect
from stid.models.model import Model
from stid.vehicle_file import load_vehicle

VEHICLE = load_vehicle(REPO / "docs" / "examples" / "rc8.toml")
DOC = (REPO / "docs" / "writing_an_effect.md").read_text()


def _doc_effect_code() -> str:
    return re.findall(r"```python\n(.*?)```", DOC, re.S)[0]


@pytest.fixture
def gyro_scale():
    ns: dict = {}
    exec(compile(_doc_effect_code(), "docs/writing_an_effect.md", "exec"), ns)
    yield ns["GyroScale"]
    unregister_effect("gyro_scale")


def _steer(n=1500, dt=0.01):
    rng = np.random.default_rng(0)
    from scipy import signal

    return signal.sosfiltfilt(signal.butter(4, 3.0, fs=1 / dt, output="sos"), 0.04 * rng.standard_normal(n)), dt


def _check_contract(name):
    cls = available_effects()[name]
    assert cls.name == name and cls.physics and cls.signature
    assert cls.stage in ("input", "tyre", "output")
    for p in cls.params:
        assert p.unit and p.doc
        lo, hi = p.value("lower", VEHICLE), p.value("upper", VEHICLE)
        assert lo <= p.value("init", VEHICLE) <= hi
    # some parameter switches the effect off (others, like a roll frequency, need not)
    assert any(q.zero is not None for q in cls.params), f"{name}: no parameter has a zero value"
    base = Model("bicycle", VEHICLE)
    model = Model(f"bicycle+{name}", VEHICLE)
    p = model.defaults()
    p.update(Cf=400.0, Cr=475.0, Iz=0.25)
    sys = model.build(p, 5.0)
    n = len(sys.states)
    assert sys.A.shape == (n, n) and sys.B.shape[0] == n and sys.C.shape[1] == n
    assert {"ay", "r"} <= set(sys.outputs) and sys.inputs[0] == "delta"
    u, dt = _steer()
    y = model.simulate(p, u, dt, 5.0)
    assert y.shape == (len(u), 2) and np.all(np.isfinite(y))
    # zero-parameter limit equals the base model ...
    pz, pb = dict(p), dict(p)
    for q in cls.params:
        if q.zero is not None:
            pz[q.name] = q.zero
            lo, hi = q.value("lower", VEHICLE), q.value("upper", VEHICLE)
            pb[q.name] = min(max(q.zero, lo), hi)
    y0 = base.simulate({k: p[k] for k in ("Cf", "Cr", "Iz")}, u, dt, 5.0)
    yz = model.simulate(pz, u, dt, 5.0)
    assert np.max(np.abs(yz - y0)) < 1e-3 * np.max(np.abs(y0)), name
    # ... and is (nearly) reachable inside the bounds, so a fit with the effect can never be
    # worse than one without it
    yb = model.simulate(pb, u, dt, 5.0)
    assert np.max(np.abs(yb - y0)) < 2e-2 * np.max(np.abs(y0)), name
    # the response changes smoothly with every parameter: central differences at two steps agree
    f = np.array([0.5, 2.0])
    for q in cls.params:
        v = p[q.name] if p[q.name] != 0 else 0.1 * (q.value("upper", VEHICLE) - q.value("lower", VEHICLE))
        d = []
        for h in (1e-3, 1e-4):
            hp, hm = dict(p), dict(p)
            hp[q.name], hm[q.name] = v * (1 + h), v * (1 - h)
            if model.nonlinear:
                d.append((model.simulate(hp, u, dt, 5.0) - model.simulate(hm, u, dt, 5.0)) / (2 * h * v))
            else:
                d.append((model.freqresp(hp, f, 5.0) - model.freqresp(hm, f, 5.0)) / (2 * h * v))
        scale = np.max(np.abs(d[1])) + 1e-12
        assert np.max(np.abs(d[0] - d[1])) < 1e-2 * scale + 1e-9, (name, q.name)


@pytest.mark.parametrize("name", sorted(available_effects()))
def test_every_registered_effect_keeps_the_contract(name):
    _check_contract(name)


def test_a_user_defined_effect_keeps_the_contract(gyro_scale):
    assert "gyro_scale" in available_effects()
    _check_contract("gyro_scale")


def test_the_catalogue_holds_at_least_the_designed_effects():
    assert {"tyre_relaxation", "actuator_lag", "accel_offset", "body_roll", "tyre_saturation",
            "sensor_bias"} <= set(available_effects())


def test_a_user_defined_effect_is_found_when_hidden(simdir, gyro_scale, tmp_path):
    """The doc's GyroScale, hidden in simulated runs (their yaw rate reads 6% high), is named
    by diagnose with no other change, and the error falls when it is added."""
    import pandas as pd

    from simdata import random_steer_pair
    from stid.diagnose import diagnose
    from stid.fit.fitting import fit
    from stid.load import load_runs

    paths = []
    for src in random_steer_pair(simdir, csv=True):
        df = pd.read_csv(src)
        df["r"] *= 1.06
        out = tmp_path / src.name
        df.to_csv(out, index=False)
        paths.append(out)
    runs = load_runs(paths, VEHICLE)
    plain = fit(runs, VEHICLE, "bicycle")
    scaled = fit(runs, VEHICLE, "bicycle+gyro_scale")
    assert scaled.fit["r"] > plain.fit["r"] + 1.0
    assert scaled.value("gyro_scale_err") == pytest.approx(0.06, abs=0.01)
    (d,) = diagnose(runs, VEHICLE, "bicycle")
    assert d.best is not None and d.best.effect == "gyro_scale", [(c.effect, c.significant) for c in d.candidates]
