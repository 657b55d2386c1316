"""The vehicle file's [params] (init, min, max per parameter) reach every fit: its start and its
bounds (stid.models.params.Param.value, which every fit, start and bound reads). Data written
from plain physics (tests/test_bad_input.py: a linear single track integrated by scipy, the
reference car, Iz 0.25 kg m^2, no servo lag)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from conftest import REPO, tool
from stid.errors import InputError
from stid.fit.fitting import fit
from stid.load import load_csv
from stid.models.model import Model
from stid.vehicle_file import load_vehicle
from test_bad_input import IZ, bicycle_run, write_csv

RC8 = (REPO / "docs" / "examples" / "rc8.toml").read_text()


def vehicle_with(tmp_path, params: str, name="v.toml"):
    path = tmp_path / name
    path.write_text(RC8 + "\n[params]\n" + params)
    return load_vehicle(path)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    path = write_csv(tmp_path_factory.mktemp("params") / "run.csv", bicycle_run(5.0, seed=3))
    return [load_csv(path)]


def test_the_start_and_the_range_are_the_models(tmp_path):
    v = vehicle_with(tmp_path, "Iz = { init = 0.1, max = 0.2 }\ntau_steer = { min = 0.01, max = 0.2 }\n")
    m = Model("bicycle+actuator_lag", v)
    assert m.defaults()["Iz"] == 0.1 and m.bounds("Iz")[1] == 0.2
    assert m.bounds("Iz")[0] == m.param("Iz").catalogue("lower", v)  # what the file leaves out stays
    assert m.bounds("tau_steer") == (0.01, 0.2) and m.defaults()["tau_steer"] == 0.05


@pytest.mark.parametrize("method", ["time", "freq"])
def test_a_bound_below_what_the_data_ask_holds_the_fit_and_gives_no_interval(tmp_path, runs, method):
    """The car's Iz is 0.25 kg m^2: fitted freely it comes out there; with max = 0.2 in the file
    the fit ends on that bound, and says so (at_bound, no interval), by either dynamic method."""
    free = fit(runs, load_vehicle(REPO / "docs" / "examples" / "rc8.toml"), "bicycle", method)
    assert free.value("Iz") == pytest.approx(IZ, rel=0.05), free.table()
    bounded = fit(runs, vehicle_with(tmp_path, "Iz = { init = 0.15, max = 0.2 }\n"), "bicycle", method)
    doc = bounded.to_json()["params"]["Iz"]
    assert doc["value"] == pytest.approx(0.2, rel=1e-3) and doc["at_bound"] and doc["ci95"] is None, doc


def test_a_range_that_keeps_an_effect_on_is_said_not_called_a_failed_fit(tmp_path, runs):
    """tau_steer >= 30 ms on a car with no servo lag: bicycle+actuator_lag no longer contains the
    bicycle, fits worse than it, and says why instead of 'the solver did not find its optimum'."""
    v = vehicle_with(tmp_path, "tau_steer = { init = 0.05, min = 0.03 }\n")
    base = fit(runs, v, "bicycle", "time")
    res = fit(runs, v, "bicycle+actuator_lag", "time")
    assert res.value("tau_steer") == pytest.approx(0.03, rel=1e-3)
    assert res.fit["r"] < base.fit["r"], (res.fit, base.fit)
    assert any("keeps tau_steer off the value where its effect vanishes" in n for n in res.notes), res.notes
    assert "did not find its optimum" not in (res.status or "")


def test_the_steady_state_lines_say_the_file_does_not_reach_them(tmp_path):
    from stid.fit.dataset import SteadyPoints
    from stid.fit.steady_fit import fit_steady

    v = vehicle_with(tmp_path, "Cf = { init = 300.0 }\n")
    ay = np.linspace(0.5, 5.0, 12)
    pts = SteadyPoints(steer=0.01 + 0.02 * ay, ay=ay, r=ay / 4.0, vx=np.full(12, 4.0), beta=None)
    res = fit_steady(Model("bicycle", v), pts)
    assert any("[params] (Cf) set no start and no bound" in w for w in res.warnings), res.warnings


@pytest.mark.parametrize("params, said", [
    ("Iz = { min = 0.3, max = 0.2 }\n", "leaves no range: min 0.3 is not below max 0.2"),
    ("Cf = { max = 100.0 }\n", "the start 403.8 lies outside [15.14, 100]"),
    ("tau_steer = { min = 0.0 }\n", "its min must be above 0"),
    ("k3 = { init = 6.0 }\n", "the start 6 lies outside [-5, 5]"),
])
def test_a_range_that_cannot_be_fitted_is_refused_when_the_file_is_read(tmp_path, params, said):
    with pytest.raises(InputError, match="catalogue: init") as e:
        vehicle_with(tmp_path, params)
    assert said in str(e.value), str(e.value)


def test_the_command_says_it_in_one_line(tmp_path, runs):
    path = tmp_path / "bad.toml"
    path.write_text(RC8 + "\n[params]\nIz = { min = 0.3, max = 0.2 }\n")
    r = subprocess.run([tool("stid"), "fit", runs[0].meta["source"], "--vehicle", str(path)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "[params] Iz" in r.stderr, r.stderr


def test_fits_worse_says_by_how_much_in_the_likelihood_that_decides():
    """'fits worse than bicycle (ay 99.6% vs 99.6%   r 99.0% vs 99.0%)' read as a contradiction: the
    likelihood decides, and the fit percents round alike. The words give the likelihood's gap."""
    from types import SimpleNamespace

    from stid.fit.nested import say_worse

    inner = SimpleNamespace(model="bicycle", loglik=1000.0, fit={"ay": 99.61, "r": 99.02})
    result = SimpleNamespace(model="bicycle+tyre_saturation", loglik=992.8, fit={"ay": 99.58, "r": 99.01},
                             status="", converged=True, names=["Cf"], undetermined={})
    say_worse(result, inner)
    assert "log-likelihood 7.2 lower" in result.status and not result.converged, result.status
