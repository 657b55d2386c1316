"""Model parameters: name, unit, physical meaning, initial value and bounds."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Param:
    """One identifiable parameter.

    ``init``, ``lower`` and ``upper`` may be numbers or callables of the vehicle
    (so defaults scale from a 1:8 car to a passenger car). ``log`` parameters are
    positive and fitted in log space (scale-free, bounded away from zero).
    ``zero`` is the value at which the parameter's effect vanishes (used by the
    contract tests: the effect at its zero equals the model without it).
    """

    name: str
    unit: str
    doc: str
    init: object
    lower: object
    upper: object
    log: bool = True
    zero: float | None = None
    multistart: bool = True  # also try 0.3x and 3x the initial value (non-convex costs)

    def value(self, attr, vehicle):
        v = getattr(self, attr)
        return float(v(vehicle) if callable(v) else v)


def unit_suffix(unit: str) -> str:
    """What follows a value in text: " m", or nothing for a pure number (its unit is "-")."""
    return f" {unit}" if unit and unit != "-" else ""
