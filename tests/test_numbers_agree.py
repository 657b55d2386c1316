"""Numbers that would disagree say why, on the spot (issue 24 point 3): an interval much wider
than its standard error names how wide, and a model far below its noise floor says its
intervals hold only if it were right."""

import json
import subprocess

import numpy as np

from conftest import REPO, tool
from simdata import random_steer_pair
from stid.fit.result import FitResult


def test_a_widened_interval_says_how_many_standard_errors_it_spans():
    res = FitResult(model="bicycle", method="time", names=["Cf", "Iz"], values=np.array([400.0, 0.25]),
                    cov=np.diag([0.2 ** 2, 0.001 ** 2]), units={"Cf": "N/rad", "Iz": "kg m^2"}, n=10_000,
                    ci_allowance=np.array([1.1, 0.0]), interval="95% intervals: with model error")
    text = res.table()
    cf = next(line for line in text.splitlines() if line.strip().startswith("Cf"))
    iz = next(line for line in text.splitlines() if line.strip().startswith("Iz"))
    # Cf's half-width 1.96 x 0.2 + 1.1 = 1.49 is 7.5 standard errors; Iz's is the noise's alone
    assert cf.endswith("(+-7.5 se)") and "se)" not in iz
    assert "a row marked (+-N se)" in text


def test_a_model_far_below_its_floor_says_its_intervals_assume_it_right(simdir):
    paths = random_steer_pair(simdir, ("actuator_lag", "accel_offset"))
    vehicle = str(REPO / "docs" / "examples" / "rc8.toml")
    r = subprocess.run([tool("stid"), "fit", *map(str, paths), "--vehicle", vehicle, "--model", "bicycle",
                        "--method", "time"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "its intervals hold only if the model were right" in r.stdout
    j = subprocess.run([tool("stid"), "fit", *map(str, paths), "--vehicle", vehicle, "--model", "bicycle",
                        "--method", "time", "--json"], capture_output=True, text=True, timeout=300)
    doc = json.loads(j.stdout)
    assert doc["below_floor"]["ay"] > 10  # the servo lag costs the bicycle tens of points
