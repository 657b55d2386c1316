"""The diagnosis's first answer, found in the background.

``stid diagnose RUN --json`` (the command, through its documented JSON) runs as a
process of its own at the lowest priority on the file as it is then, whenever the data
have grown enough since the last try; the live view shows its verdict meanwhile. A
diagnosis takes seconds to minutes: the updates never wait for it, and it never delays
the logger (it is niced below both).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

MIN_DRIVING_S = 15.0  # less than this carries no diagnosis worth waiting for
GROWTH = 1.5  # try again once the data are this many times what the last try saw
NICE = 19


class BackgroundDiagnosis:
    def __init__(self, path, vehicle_path: str | None, model: str):
        self.path = str(path)
        self.vehicle_path = vehicle_path
        self.model = model
        self.proc: subprocess.Popen | None = None
        self.tried_at = 0.0  # driving seconds the last try saw
        self.running_at = 0.0
        self.text: str | None = None  # the verdict shown
        self.effect: str | None = None  # the effect it names (None: nothing named, or not yet)
        self.unexplained = False  # the model is short of the noise floor, and no catalogue effect explains it
        self.runs = 0

    def poll(self, driving_s: float, finished: bool = False, wait: bool = False) -> str | None:
        """Collect a finished try, start the next when due; the verdict to show. ``wait``: the view
        shows this update only (a single update, or a file already finished when it was opened): a
        diagnosis of the data is run to its end now, once there is driving enough, since without
        it a reached target is not the answer (a single update said "done: the run is enough" for a
        model that missed an accelerometer offset, every interval beside the truth)."""
        if self.vehicle_path is None:
            return None
        if wait and self.proc is None and self.tried_at == 0 and driving_s >= MIN_DRIVING_S:
            self._start(driving_s, nice=False)  # (waited for: the user's foreground work now)
        # (communicate, not wait: the JSON may be more than a pipe holds)
        if self.proc is not None and (wait or self.proc.poll() is not None):
            out, _ = self.proc.communicate()
            self.text = verdict(out, self.running_at) or self.text
            if self.text:
                self.effect, self.unexplained = named_effect(out), unexplained(out)
            self.tried_at = self.running_at
            self.proc = None
        # (none started on a finished file: the view ends after its last update; `stid diagnose`
        # on the file is the command for the whole run)
        due = (not finished and driving_s >= MIN_DRIVING_S
               and (self.tried_at == 0 or driving_s >= GROWTH * self.tried_at))
        if self.proc is None and due:
            self._start(driving_s)
        if self.text is None:
            if self.proc is not None:
                return f"diagnosis: looking at the first {self.running_at:.0f} s of driving ..."
            return f"diagnosis: once {MIN_DRIVING_S:.0f} s of driving are recorded"
        return self.text

    def _start(self, driving_s: float, nice: bool = True) -> None:
        cmd = [*_stid_command(), "diagnose", self.path, "--vehicle", self.vehicle_path, "--model", self.model,
               "--json"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     preexec_fn=(lambda: os.nice(NICE)) if nice else None)
        self.running_at = driving_s
        self.runs += 1

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _stid_command() -> list:
    """The `stid` console script beside this interpreter, as a user types it: a warm `stid serve`
    then takes the diagnosis (stid.serve; a server answers only a command of its own sys.path, and
    `python -m stid.cli` puts the working directory first, so it never found one and loaded numpy,
    scipy and numba for every try); `python -m stid.cli` where there is no such script."""
    script = os.path.join(os.path.dirname(sys.executable), "stid")
    return [script] if os.access(script, os.X_OK) else [sys.executable, "-m", "stid.cli"]


def named(doc: dict) -> list:
    """The effects a round tells the user to add: ``named`` (one, or a pair), or in an older
    diagnosis the best significant candidate."""
    if isinstance(doc.get("named"), list):
        return [str(e) for e in doc["named"]]
    best = next((c for c in doc.get("candidates", []) if c.get("significant")), None)
    return [best["effect"]] if best else []


def verdict(output: str, driving_s: float) -> str | None:
    """One line from ``stid diagnose --json``: what it names with their parameters, or that
    nothing is missing; None when the output is not a diagnosis."""
    doc = _diagnosis(output)
    if doc is None:
        return None
    effects = named(doc)
    at = f"(stid diagnose, {driving_s:.0f} s of driving)"
    if not effects:
        model = doc.get("model", "the model")
        stuck = [c["effect"] for c in doc.get("candidates", []) if c.get("converged") is False]
        if stuck and _unexplained(doc):  # (stid.present: the catalogue is not ruled out while one stopped short)
            return (f"diagnosis: nothing named, and the catalogue is not ruled out: the fit of "
                    f"{', '.join(f'{model}+{e}' for e in stuck)} did not converge; stid diagnose on the file says "
                    f"more {at}")
        if _unexplained(doc):
            gaps = ", ".join(f"{o} {doc['fit'][o]:.1f}% where the noise allows {doc['noise_floor'][o]:.1f}%"
                             for o in ("ay", "r") if o in doc.get("fit", {}) and o in doc.get("noise_floor", {}))
            return (f"diagnosis: {model} misses something no effect of the catalogue explains"
                    f"{' (' + gaps + ')' if gaps else ''}; stid diagnose on the file says what is left {at}")
        if doc.get("above_floor"):  # (the floor is then no reference: stid.analysis.noise_floor.above_floor)
            return (f"diagnosis: nothing more named: {model} fits above the noise floor "
                    f"({', '.join(doc['above_floor'])}), which then cannot say whether something is still missing {at}")
        late = doc.get("delay_seen_ms") or {}
        if late.get("intervals_allow_for_it"):  # (a delay moves Iz by percents for a fraction of a fit point)
            way = "later" if late["value"] > 0 else "earlier"
            return (f"diagnosis: no effect gains fit points, but the outputs answer the steer {abs(late['value']):.2f} "
                    f"ms {way} than {model} has them (its intervals allow for it) {at}")
        return f"diagnosis: nothing missing from {model} that these data show {at}"
    shown = {}
    for c in doc["candidates"]:
        if c.get("effect") in effects:
            units = c.get("units", {})
            for n, v in (c.get("params") or {}).items():
                shown.setdefault(n, _quantity(n, v, units.get(n, "")))
    values = ", ".join(shown.values())
    return f"diagnosis: {' + '.join(effects)} likely{': ' + values if values else ''}{_still_short(doc)} {at}"


def _still_short(doc: dict) -> str:
    """What the named model still misses, when it is short of the noise floor by more than chance
    and MIN_GAP (stid.analysis.unexplained's rule): then something more is missing, and it bends
    the values shown (the demo's 6 m/s run alone: a servo lag of 39 ms where the car has 60, with
    the accelerometer's offset from the CG not yet found)."""
    from stid.analysis.unexplained import MIN_GAP, Z

    left = doc.get("unexplained")
    gap = left.get("gap") if isinstance(left, dict) else None
    if not isinstance(gap, dict):
        return ""
    se = doc.get("noise_floor_stderr") or {}
    short = [f"{o} {g:.1f}" for o, g in gap.items()
             if isinstance(g, (int, float)) and g > max(MIN_GAP, Z * float(se.get(o) or 0.0))]
    if not short:
        return ""
    return (f"; with it still {', '.join(short)} points short of the noise floor: something more is missing, "
            "and it may bend these values (stid diagnose --peel on the file)")


def named_effect(output: str) -> str | None:
    """What to add to the model (``a+b`` for a pair), or None."""
    doc = _diagnosis(output)
    if doc is None:
        return None
    return "+".join(named(doc)) or None


def unexplained(output: str) -> bool:
    """The diagnosis names nothing, yet the model is short of its noise floor by more than
    chance: an effect the catalogue lacks (or one of its effects it could not tell)."""
    doc = _diagnosis(output)
    return doc is not None and not named(doc) and _unexplained(doc)


def _diagnosis(output: str) -> dict | None:
    """The document of ``stid diagnose --json``; None for any other output (an error, nothing)."""
    try:
        doc = json.loads(output)
    except (json.JSONDecodeError, TypeError):
        return None
    return doc if isinstance(doc, dict) and "candidates" in doc else None


def _unexplained(doc: dict) -> bool:
    left = doc.get("unexplained")
    return isinstance(left, dict) and bool(left.get("significant"))


def _quantity(name: str, value: float, unit: str) -> str:
    """A parameter in the unit a person reads it in (ms for a lag, cm for an offset, deg)."""
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return f"{name} ?"
    if unit == "s" and abs(value) < 1:
        return f"{name} {value * 1e3:.0f} ms"
    if unit == "m" and abs(value) < 1:
        return f"{name} {value * 1e2:.1f} cm"
    if unit == "rad":
        return f"{name} {math.degrees(value):.2f} deg"
    return f"{name} {value:.3g} {unit}".rstrip()
