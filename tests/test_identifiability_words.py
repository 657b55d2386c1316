"""The warnings on a fit agree with the numbers printed beside them: a correlation printed as
+0.98 ("strongly correlated: Cf-Cr +0.98") carries the "almost fully correlated" warning."""

from __future__ import annotations

import numpy as np
import pytest

from stid.fit import checks
from stid.fit.result import FitResult
from stid.models.model import Model
from stid.vehicle_file import Vehicle


def _result(r: float) -> FitResult:
    names = ["Cf", "Cr", "Iz"]
    se = np.array([10.0, 10.0, 0.001])
    corr = np.array([[1.0, r, 0.0], [r, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return FitResult(model="bicycle", method="time", names=names, values=np.array([500.0, 600.0, 0.05]),
                     cov=corr * np.outer(se, se), units={"Cf": "N/rad", "Cr": "N/rad", "Iz": "kg m^2"})


@pytest.mark.parametrize("r, warned", [(0.9798, True), (-0.9751, True), (0.9749, False), (0.5, False)])
def test_a_correlation_printed_as_0_98_is_warned_of(r, warned):
    result = _result(r)
    checks.add_identifiability_warnings(result, Model("bicycle", Vehicle("plain", 2.0, 0.15, 0.15)), [])
    printed = result.table()
    said = [w for w in result.warnings if "almost fully correlated" in w]
    assert bool(said) == warned, (r, result.warnings)
    if warned:
        assert f"Cf-Cr {r:+.2f}" in printed and f"{r:+.3f}" in said[0], (printed, said)
