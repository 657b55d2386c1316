"""Evidence before a name: an effect explains the data only if its signature holds
across the evidence, not merely if adding it improves the fit.

The stretches are split by the conditions the runs hold apart (speed; steer
amplitude) and the model with the effect is refitted on each part by the one
fitting path. A physical parameter is a property of the car: it must come out
inside its plausible range (not stopped at a bound: a mu of 3) and as one value at
every speed and amplitude within the intervals (a 12 cm sensor offset that moves
with speed, a lag that differs between runs are not evidence; they are another
effect bending a parameter to mimic it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stid.fit.result import at_resolution
from stid.models.params import unit_suffix

SPEED_STEP = 1.15  # a new speed group starts 15% above the last one's slowest stretch
AMP_STEP = 1.5  # a new amplitude group starts at 1.5x the last one's smallest steer rms
MIN_GROUP_S = 10.0  # seconds of data a group needs for its own fit
STEERED_HZ, STEERED_SHARE = 0.5, 0.25  # steering: a quarter of the steer's variance above 0.5 Hz (_steered)
Z99_OVER_Z95 = 2.576 / 1.96  # the intervals are 95%; the test is at 99% (several parameters, pairs)
# Two values are "not one value" only when they differ beyond their intervals AND by more than
# this share of the larger: the intervals hold noise and the model error that varies within a
# run, not the few percent a linear model's small differences from the car move a parameter
# between speeds (measured on the simulator: its accelerometer 8.0 cm ahead of the CG fits as
# 8.2 cm at 4 m/s and 8.0 cm at 6 m/s, each interval +-1 mm). The examples a name must not
# survive move far more: relaxation mimicking a servo lag fits sigma in proportion to speed
# (+50% from 4 to 6 m/s); an offset standing in for another effect moves by its size.
MATERIAL = 0.15


@dataclass
class Group:
    label: str
    stretches: list
    result: object = None


@dataclass
class Evidence:
    holds: bool
    reason: str = ""
    partitions: dict = field(default_factory=dict)  # "speed" -> [Group]

    def to_json(self) -> dict:
        return {"holds": self.holds, "reason": self.reason,
                "by": {k: [{"group": g.label, "params": {n: [float(v), float(lo), float(hi)] for n, v, (lo, hi)
                                                         in zip(g.result.names, g.result.values, g.result.ci95)}}
                           for g in gs if g.result is not None] for k, gs in self.partitions.items()}}


def _split(stretches, key, step, label):
    order = sorted(stretches, key=key)
    groups, start = [], None
    for st in order:
        if start is None or key(st) > step * start:
            groups.append([])
            start = key(st)
        groups[-1].append(st)
    seconds = [sum(len(s.t) * s.dt for s in g) for g in groups]
    kept = [g for g, s in zip(groups, seconds) if s >= MIN_GROUP_S]
    return [Group(label(g), g) for g in kept] if len(kept) >= 2 else []


def speed_pieces(stretches) -> list:
    """The stretches, each one that holds two or more separate speeds (SPEED_STEP apart) for
    MIN_GROUP_S each as its pieces at those speeds (the speed changes between them are left out):
    one run driven 29 s at 3 m/s and 29 s at 6 m/s is one stretch, and was called "never held at
    two separate speeds" with advice to drive what it held (a trial user's)."""
    out = []
    for st in stretches:
        hit = _PIECES.get(id(st))
        if hit is None or hit[0] is not st:  # (the stretch is held: its id is not reused while cached)
            if len(_PIECES) >= 64:
                _PIECES.pop(next(iter(_PIECES)))
            hit = _PIECES[id(st)] = (st, _held_pieces(st))  # (the words ask for them often: 6 ms a call)
        out.extend(hit[1])
    return out


_PIECES: dict = {}


def _held_pieces(st) -> list:
    from stid import segments

    found = segments.constant_speed(np.asarray(st.vx_series, float), 1.0 / st.dt, min_s=MIN_GROUP_S)
    speeds = [float(np.median(st.vx_series[a:b])) for a, b in found]
    if len(found) < 2 or max(speeds) <= SPEED_STEP * min(speeds):
        return [st]
    return [st.cut(a, b, name=f"{st.name} at {v:.1f} m/s", vx=v) for (a, b), v in zip(found, speeds)]


def partitions(stretches) -> dict:
    """The conditions the runs hold apart, each with at least two groups of enough data."""
    out = {}
    by_speed = _split(speed_pieces(stretches), lambda s: s.vx, SPEED_STEP,
                      lambda g: f"{np.median([s.vx for s in g]):.1f} m/s")
    if by_speed:
        out["speed"] = by_speed
    by_amp = _split([s for s in stretches if _steered(s)], lambda s: float(np.std(s.steer)), AMP_STEP,
                    lambda g: f"steer {np.degrees(np.median([np.std(s.steer) for s in g])):.1f} deg rms")
    if by_amp:
        out["amplitude"] = by_amp
    return out


def _steered(st) -> bool:
    """Whether a stretch's steer is steering: most of its variance above STEERED_HZ. A steer held or
    swept slowly (a steady circle: 3% of it above 0.5 Hz, where random steer has 86-92%) has no
    amplitude of steering to compare; fitted as its own "steer 0.7 deg rms" group, a trial's 2 g
    circle found no servo lag in its corrections and vetoed the one the random steer showed.
    The share is a ratio of sums over many bins, so one Hann-windowed periodogram gives it as
    Welch's average does (the window keeps a slow sweep's power from leaking upward), without
    importing scipy.signal, which brings scipy.stats: 0.36 s in a process that has loaded the rest
    of scipy (stid.fit.filters)."""
    x = np.asarray(st.steer, float)
    fs = 1.0 / float(st.dt)
    if len(x) < 16 or not np.std(x) > 0:
        return False
    P = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / fs)
    return bool(P[f >= STEERED_HZ].sum() >= STEERED_SHARE * P.sum())


def _fit_group(job):
    from stid.fit.dataset import Stretches
    from stid.fit.fitting import fit

    model_name, vehicle, stretches, init = job
    return fit((), vehicle, model_name, "time", stretches=Stretches(stretches), init=init, multistart=False)


def fit_groups(model_name: str, vehicle, stretches, init: dict, mapper=map) -> dict:
    """Each partition's groups, each fitted on its own (from ``init``). ``mapper``: a
    map over the independent fits (stid.diagnose passes its worker pool's)."""
    parts = partitions(stretches)
    groups = [g for gs in parts.values() for g in gs]
    for g, res in zip(groups, mapper(_fit_group, [(model_name, vehicle, g.stretches, init) for g in groups])):
        g.result = res
    return parts


def at_bound(result, names, model) -> list:
    return [n for n in names if model.at_bound(n, result.value(n))]


def _where_it_vanishes(model, name: str, value: float) -> bool:
    """Whether ``value`` sits at the end of ``name``'s range beyond which its effect vanishes."""
    return model.at_vanishing_end(name, value)


def disagreements(parts: dict, names, material: float = MATERIAL) -> list:
    """Parameters that are not one value across a partition's groups: (partition, name, text).
    ``material``: the share of the larger value they must differ by too (0: beyond their
    intervals is enough)."""
    out = []
    for kind, groups in parts.items():
        for n in names:
            # shown with the intervals they are compared by (without a delay's allowance, which
            # moves every group alike: FitResult.half95_between_groups)
            vals = [(g.label, g.result.value(n), dict(zip(g.result.names, g.result.ci95_between_groups)).get(n),
                     dict(zip(g.result.names, g.result.half95_between_groups)).get(n),
                     dict(zip(g.result.names, g.result.stderr)).get(n)) for g in groups]
            vals = [v for v in vals if v[2] is not None and np.all(np.isfinite(v[2]))]
            bad = False
            for i in range(len(vals)):
                for j in range(i + 1, len(vals)):
                    hi_, hj = Z99_OVER_Z95 * vals[i][3], Z99_OVER_Z95 * vals[j][3]  # (half-widths)
                    diff = abs(vals[i][1] - vals[j][1])
                    if diff > np.hypot(hi_, hj) and diff > material * max(abs(vals[i][1]), abs(vals[j][1])):
                        bad = True
            if bad:
                unit = unit_suffix(groups[0].result.units.get(n, ""))
                txt = ", ".join(f"{at_resolution(v, se)} [{at_resolution(ci[0], se)}, {at_resolution(ci[1], se)}]"
                                f"{unit} at {lab}" for lab, v, ci, _, se in vals)
                out.append((kind, n, f"{n} {txt}"))
    return out


def check_evidence(model_name: str, effect: str, vehicle, stretches, result, mapper=map, parts=None) -> Evidence:
    """Does the effect's parameter hold as one plausible value across the evidence?
    ``mapper``: as in ``fit_groups``; ``parts``: the groups' fits of ``model_name`` when the
    caller has them (a second effect of the same model is checked on the same fits)."""
    from stid.models.model import Model

    model = Model(model_name, vehicle)
    own = [n for n in result.names if result.owners.get(n) == effect]
    stuck = at_bound(result, own, model)
    if stuck:
        values = ", ".join(f"{n} = {result.value(n):.4g}{unit_suffix(result.units.get(n, ''))}" for n in stuck)
        if all(_where_it_vanishes(model, n, result.value(n)) for n in stuck):
            # (a rear relaxation length at its lower end is no tyre beyond physics, but none seen: a real
            # car's log was told "outside what the physics allows" for sigma_r -> 0)
            return Evidence(False, f"its parameter went to the end of its range where that part of the effect "
                            f"vanishes ({values}): the data show none of it there, so the effect as the catalogue "
                            "has it is not what they show")
        return Evidence(False, f"its parameter stopped at the edge of the plausible range ({values}): the data push "
                        "it outside what the physics allows")
    parts = parts if parts is not None else fit_groups(model_name, vehicle, stretches, result.all_params(), mapper)
    for kind, groups in parts.items():
        for g in groups:
            if not g.result.converged:  # its values are where a solver stopped: they show nothing
                return Evidence(False, f"fitted at {g.label} alone, the fit did not converge ({g.result.status})",
                                parts)
            s = at_bound(g.result, own, model)
            if s:
                return Evidence(False, f"fitted at {g.label} alone, {', '.join(s)} stopped at a bound "
                                f"({', '.join(f'{n} = {g.result.value(n):.4g}' for n in s)})", parts)
    bad = disagreements(parts, own)
    if bad:
        kind, _, text = bad[0]
        return Evidence(False, f"its parameter is not one value across {kind}: {text}", parts)
    return Evidence(True, "", parts)
