"""The precision each parameter should reach: ``--target Iz=3%`` on the command line, the
vehicle file's ``[targets]`` table, or the default.

A target is the 95% interval's half-width in percent of the value (the number the live
view shows as ``±3.0%``). ``stid plan --target`` means a standard error instead (about
half of it): the live view shows what the user will read in ``stid fit``'s interval.
"""

from __future__ import annotations

import math

from stid.errors import InputError

# Without a target given, every parameter that is positive by nature (a stiffness, an
# inertia, a lag, a length) should reach +-5%; a signed one (an offset, a bias) has no
# relative precision (its value may be 0) and gets a target only when the user names it.
DEFAULT_PERCENT = 5.0


def parse_percent(text, where: str) -> float:
    """``3%``, ``"3%"`` or ``3`` (percent) -> 3.0; refused outside (0, 100)."""
    if isinstance(text, bool):
        raise InputError(f"{where}: a target is a percent, e.g. 3%, got {text!r}")
    if isinstance(text, (int, float)):
        value = float(text)
    else:
        s = str(text).strip()
        try:
            value = float(s[:-1] if s.endswith("%") else s)
        except ValueError:
            raise InputError(f"{where}: a target is a percent, e.g. 3%, got {text!r}") from None
    if not (0 < value < 100) or not math.isfinite(value):
        raise InputError(f"{where}: a target is the 95% interval's half-width in percent of the value, above 0 "
                         f"and below 100, e.g. 3%; got {text!r}")
    return value


def parse_cli(items) -> dict:
    """``["Iz=3%", "Cf=2"]`` -> {"Iz": 3.0, "Cf": 2.0} (percent)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--target {item!r}: write NAME=PERCENT, e.g. Iz=3%")
        name, value = item.split("=", 1)
        out[name.strip()] = parse_percent(value, f"--target {item}")
    return out


def choose(model, given: dict, vehicle_targets: dict) -> tuple[dict, str]:
    """Targets for ``model``'s parameters: those given (``--target``), else the vehicle
    file's, else DEFAULT_PERCENT for the positive ones. (targets in percent, where from)."""
    names = list(model.param_names)
    for source, table in (("--target", given), ("the vehicle file's [targets]", vehicle_targets)):
        for name in table:
            if name not in names and source == "--target":
                raise InputError(f"--target {name}: the model {model.name} has no parameter {name}; its "
                                 f"parameters: {', '.join(names)}")
    if given:
        return dict(given), "--target"
    mine = {n: v for n, v in vehicle_targets.items() if n in names}
    if mine:
        return mine, "the vehicle file's [targets]"
    return ({n: DEFAULT_PERCENT for n in names if model.param(n).log},
            f"the default, ±{DEFAULT_PERCENT:g}% for every parameter positive by nature")
