"""The speeds the data hold, in words that count speeds, not runs or stretches.

One run on a track can span 1.2-4.4 m/s, and two runs can hold one speed: what a reader
needs is how many speeds the parameters were tested at (stid.analysis.evidence splits
the stretches by speed only where each speed holds MIN_GROUP_S of stretches of its own),
and the range the data cover when the speed varies within the runs."""

from __future__ import annotations

import numpy as np

from stid.analysis.evidence import MIN_GROUP_S, SPEED_STEP, speed_pieces


def _label(v: float) -> str:
    return f"{round(v, 1):g}"


def speed_range(stretches) -> tuple:
    """The speeds the samples cover: 5th and 95th percentiles [m/s] (a brake or a kick at one
    end does not widen it)."""
    v = np.concatenate([s.vx_series for s in stretches])
    lo, hi = np.percentile(v, [5, 95])
    return float(lo), float(hi)


def held_speeds(stretches) -> list:
    """The separate speeds the stretches are driven at (their medians, a new speed 15% above the
    last; a stretch that holds two speeds for MIN_GROUP_S each counts as its pieces), slowest
    first, each as (median speed, seconds of stretches)."""
    out = []
    for st in sorted(speed_pieces(stretches), key=lambda s: s.vx):
        if not out or st.vx > SPEED_STEP * out[-1][2]:
            out.append([[], 0.0, st.vx])
        out[-1][0].append(st.vx)
        out[-1][1] += len(st.t) * st.dt
    return [(float(np.median(v)), float(s)) for v, s, _ in out]


def varies(stretches) -> bool:
    """Whether the speed moves within the stretches by more than one speed's width."""
    lo, hi = speed_range(stretches)
    return hi > SPEED_STEP * lo


def spans_speeds(stretches) -> bool:
    """Whether the data can say anything about a change with speed: two separate speeds held, or
    a speed that varies within the runs. A run held at one speed shows what a model predicts
    there, not how anything changes with speed."""
    return len(held_speeds(stretches)) > 1 or varies(stretches)


def stretch_speeds(stretches) -> str:
    """Each stretch's speed, a range where it varies within it: '3.1, 7.2 m/s', '1.2-4.4 m/s'."""
    labels = []
    for st in sorted(stretches, key=lambda s: s.vx):
        lo, hi = speed_range([st])
        lab = f"{lo:.1f}-{hi:.1f}" if hi > SPEED_STEP * lo else _label(st.vx)
        if lab not in labels:
            labels.append(lab)
    return ", ".join(labels) + " m/s"


def at_speeds(stretches) -> str:
    """Where a fit's numbers were seen: 'at every speed (4, 6 m/s)', 'over 1.2-4.4 m/s (...)' or
    'at 4 m/s (one speed only)'."""
    held = held_speeds(stretches)
    if len(held) > 1:
        return "at every speed (" + ", ".join(_label(v) for v, _ in held) + " m/s)"
    if varies(stretches):
        lo, hi = speed_range(stretches)
        return f"over {lo:.1f}-{hi:.1f} m/s (the speed varies within the runs; no second steady speed)"
    return f"at {_label(held[0][0])} m/s (one speed only)"


def one_speed_words(stretches) -> str:
    """Why the data give no per-speed fits, and what to drive: for `unexplained`, where the
    evidence found no two speeds with MIN_GROUP_S of stretches each."""
    held = held_speeds(stretches)
    lo, hi = speed_range(stretches)
    todo = "to see whether the missing part changes with speed"
    if len(held) > 1:
        return (f"the data hold {len(held)} speeds (" + ", ".join(f"{_label(v)} m/s for {s:.0f} s" for v, s in held)
                + f"), too short for a fit at each (it needs {MIN_GROUP_S:g} s): drive longer at each speed " + todo)
    if hi > SPEED_STEP * lo:
        return (f"the speed varies over {lo:.1f}-{hi:.1f} m/s within the runs but is never held at two separate "
                f"speeds for {MIN_GROUP_S:g} s each: drive a stretch at a steady low and a steady high speed " + todo)
    return f"the data hold one speed ({_label(held[0][0])} m/s): drive the same manoeuvre at a second speed " + todo
