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
        """``init``, ``lower`` or ``upper`` for ``vehicle``: its file's [params] entry
        (``init``, ``min``, ``max``) where it gives one, else the catalogue's (``catalogue``).
        Every fit, start and bound reads it here, so the vehicle file reaches them all."""
        given = (getattr(vehicle, "params", None) or {}).get(self.name) or {}
        key = VEHICLE_FILE_KEYS[attr]
        if key in given:
            return float(given[key])
        return self.catalogue(attr, vehicle)

    def catalogue(self, attr, vehicle):
        """``init``, ``lower`` or ``upper`` as the model's catalogue has it (scaled to the vehicle)."""
        v = getattr(self, attr)
        return float(v(vehicle) if callable(v) else v)


VEHICLE_FILE_KEYS = {"init": "init", "lower": "min", "upper": "max"}  # Param attribute -> [params] key


def unit_suffix(unit: str) -> str:
    """What follows a value in text: " m", or nothing for a pure number (its unit is "-")."""
    return f" {unit}" if unit and unit != "-" else ""
