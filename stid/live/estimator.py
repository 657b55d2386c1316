"""One live update: the fit ``stid fit --method time`` makes on the data so far, its 95%
precision per parameter against the targets, what the data still lack, and whether the
run is done.

The first fit is ``stid.fit.fitting.fit`` itself (the one path of every command). Each
later one is the same output-error fit (``fit_time``) started from the previous estimate
instead of a multistart (``settle``): it skips the first solve, which only finds the
neighbourhood, and from there both take the same steps to the same point: the outputs
weighted by the residual levels the point leaves (maximum likelihood), re-weighted until
the answer is stationary at its own weights, each solve ended by the rule the verdict
judges by (stid.fit.convergence). So the optimum and the verdict are ``stid fit``'s on the
file at that moment (tests/test_live.py, tests/test_fit_live_agree.py). The intervals are
``stid fit``'s (noise, block jackknife, geometry allowance).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from stid.errors import InputError, StidError
from stid.live import excitation, lacks
from stid.live.source import Snapshot


@dataclass
class ParamState:
    name: str
    unit: str
    value: float
    half95: float | None  # None: the data do not determine it
    target: float | None  # percent, or None (no target for it)

    @property
    def percent(self) -> float | None:
        if self.half95 is None or not self.value:
            return None
        return 100.0 * self.half95 / abs(self.value)

    @property
    def met(self) -> bool | None:
        if self.target is None:
            return None
        return self.percent is not None and self.percent <= self.target

    def to_json(self) -> dict:
        return {"name": self.name, "unit": self.unit, "value": _finite(self.value),
                "half95": _finite(self.half95), "percent": _finite(self.percent), "target": self.target,
                "met": self.met}


@dataclass
class Update:
    """What the views show after one update."""

    seq: int
    path: str
    model: str
    seconds: float = 0.0  # seconds of data so far
    driving_s: float = 0.0  # of which fitted (moving, with steering)
    params: list = field(default_factory=list)  # ParamState
    fit: dict = field(default_factory=dict)  # output -> percent
    state: list = field(default_factory=list)  # what is wrong or awaited, in words
    lacking: list = field(default_factory=list)  # what to drive next, in a driver's words
    done: str | None = None
    diagnosis: str | None = None
    excitation: dict | None = None
    events: list = field(default_factory=list)
    history: list = field(default_factory=list)  # (seconds, {name: percent}) of every update so far
    targets_from: str = ""
    finished: bool = False
    converged: bool = True  # the fit's verdict (stid.fit.convergence): an optimum, or not
    cpu_s: float = 0.0  # CPU seconds of this update (reading the file included)
    timing: dict = field(default_factory=dict)  # CPU seconds of its parts: read, fit, lacking, map
    wall: float = field(default_factory=time.time)

    def to_json(self) -> dict:
        return {"seq": self.seq, "path": self.path, "model": self.model, "seconds": round(self.seconds, 2),
                "driving_s": round(self.driving_s, 2), "params": [p.to_json() for p in self.params],
                "fit": {k: _finite(v) for k, v in self.fit.items()}, "state": self.state, "lacking": self.lacking,
                "done": self.done, "diagnosis": self.diagnosis, "excitation": self.excitation,
                "events": [{"at_s": round(a, 2), "event": e, "detail": d} for a, e, d in self.events],
                "history": [{"seconds": round(s, 2), "percent": {k: _finite(v) for k, v in p.items()}}
                            for s, p in self.history],
                "targets_from": self.targets_from, "finished": self.finished, "converged": self.converged, "cpu_s": round(self.cpu_s, 3),
                "timing": {k: _finite(round(v, 3)) for k, v in self.timing.items()},
                "wall": self.wall}


def _finite(x):
    return float(x) if x is not None and math.isfinite(x) else None


class Estimator:
    """Keeps the previous estimate (the next fit's start) and the history of precision."""

    def __init__(self, vehicle, model_name: str, targets: dict, targets_from: str = ""):
        from stid.models.model import Model

        self.vehicle = vehicle
        self.model_name = model_name
        self.model = Model(model_name, vehicle)  # a misspelt model is refused before any data comes
        # imported now, not in the first update that needs them: scipy.signal (the plan's spectra)
        # costs half a second of CPU to import, once per process
        import stid.crlb  # noqa: F401
        import stid.plan  # noqa: F401
        from stid.fit import filters

        filters.use_scipy_signal()  # loaded now: its compiled filter re-filters the growing run 4x faster
        self.targets = targets
        self.targets_from = targets_from
        self.seq = 0
        self._start: dict | None = None
        self.history: list = []
        self.last_fit = None

    def update(self, snap: Snapshot, path: str = "") -> Update:
        cpu = time.process_time()
        self.seq += 1
        up = Update(self.seq, path, self.model_name, seconds=snap.seconds, state=list(snap.state),
                    events=list(snap.events), targets_from=self.targets_from, finished=snap.finished)
        up.timing["read"] = snap.read_s
        if snap.runs:
            t = time.process_time()
            self._fit(snap.runs, up)
            up.timing["fit"] = time.process_time() - t
            t = time.process_time()
            up.lacking = lacks.lacking(snap.runs, self.last_fit if up.params else None, self.model, up.params)
            up.timing["lacking"] = time.process_time() - t
            t = time.process_time()
            up.excitation = excitation.speed_frequency_map(snap.runs)
            up.timing["map"] = time.process_time() - t
        if up.params:
            self.history.append((up.seconds, {p.name: p.percent for p in up.params}))
        up.history = list(self.history)
        up.done = done_line(up)
        up.cpu_s = time.process_time() - cpu + snap.read_s
        return up

    def _fit(self, runs, up: Update) -> None:
        from stid.fit.dataset import V_MOVING, dynamic_stretches
        from stid.fit.fitting import fit
        from stid.fit.time_fit import fit_time

        try:
            stretches = dynamic_stretches(runs)
        except InputError:
            moving = sum(float(np.sum(r.vx > V_MOVING)) / r.fs for r in runs)
            up.state.append("nothing to fit yet: " + ("the car has only stood still" if moving < 0.5 else
                                                      f"{moving:.0f} s of driving, none of it a stretch of "
                                                      "3 s with steering"))
            return
        up.driving_s = sum(len(s.t) * s.dt for s in stretches)
        try:
            if self._start is None:
                res = fit(runs, self.vehicle, self.model_name, "time")
            else:
                res = fit_time(self.model, stretches, init=self._start, multistart=False, intervals="model-error",
                               settle=True)
        except StidError as e:
            up.state.append(f"the fit failed on the data so far: {e}")
            return
        self.last_fit = res
        self._start = res.all_params()
        up.fit = dict(res.fit)
        half = res.half95
        for i, name in enumerate(res.names):
            h = float(half[i]) if np.isfinite(half[i]) else None
            up.params.append(ParamState(name, res.units.get(name, ""), float(res.values[i]), h,
                                        self.targets.get(name)))
        up.converged = bool(res.converged)
        if not up.converged:
            up.state.append(f"the fit did not converge on the data so far ({res.status}): its numbers are not an "
                            "optimum and have no intervals")
        for name, why in res.undetermined.items():
            if up.converged:
                up.state.append(f"{name}: no interval ({why}): the data so far do not determine it")


def done_line(up: Update) -> str | None:
    """The line that tells the driver to stop: every parameter with a target has reached it."""
    aimed = [p for p in up.params if p.target is not None]
    if not aimed or not up.converged or not all(p.met for p in aimed):
        return None
    reached = ", ".join(f"{p.name} ±{p.percent:.1f}% (≤ {p.target:g}%)" for p in aimed)
    return (f"done: every target of {up.model} is reached after {up.seconds:.0f} s of data ({reached}); "
            "the run is enough")
