"""A steer column that sits at its extreme for much of a run: a clip or full lock.

A teleoperated car's command is clipped at its limit (the FrictionMaps F1/10 car: +-0.34 rad,
29-45% of its runs), a transmitter at its end point, a sensor at its range. While it sits
there the column no longer says what was asked, and the fit takes the clipped value for
the road-wheel angle: right if the wheels stopped there too, wrong by whatever they turned
beyond it (a clip in the logging), and at full lock a linkage is least linear.

What sets a clip apart from a chosen amplitude: a clipped signal varies continuously and
piles up at its ends, entered again and again; a step steer or a circle sits at its
amplitude by design and has nothing in between (a circle is one visit).
"""

from __future__ import annotations

import numpy as np

from stid import segments
from stid.analysis import held_steer

CLIP_SHARE = 0.10  # of the moving time at one extreme: a tenth of the data at one input value
MIN_VISITS = 3  # entered this often: a limit the signal keeps running into, not one hold
# A chosen staircase (0, +-A) spends almost no time between its levels; a clipped command
# spends a share of its time there (FrictionMaps: 22-30%). Between: not at an extreme, and not
# at a level held for HELD_LEVEL_S.
MIN_BETWEEN_SHARE = 0.10
HELD_LEVEL_S = 0.5
TOL_SHARE = 0.005  # of the column's peak-to-peak: "at" the extreme
MOVING_MPS = 1.0


def clip_warning(run, wheelbase: float | None = None) -> str:
    """A warning when the run's steer sits at its maximum or minimum for CLIP_SHARE or more of
    the moving time in MIN_VISITS or more visits, and varies continuously otherwise; "" else."""
    steer = np.asarray(run.steer, float)
    moving = np.abs(np.asarray(run.vx, float)) > MOVING_MPS
    if moving.sum() < 10 or not np.all(np.isfinite(steer)):
        return ""
    span = float(np.ptp(steer[moving]))
    if span <= 0:
        return ""
    tol = TOL_SHARE * span
    found = []
    for ext in (float(np.max(steer[moving])), float(np.min(steer[moving]))):
        at = np.abs(steer - ext) <= tol
        share = float(np.mean(at[moving]))
        visits = len(segments.runs_of(at & moving, 1))
        if share >= CLIP_SHARE and visits >= MIN_VISITS:
            found.append((ext, share, visits, at))
    if not found or _between_share(steer, moving, [f[3] for f in found], tol, run.fs) < MIN_BETWEEN_SHARE:
        return ""
    said = " and ".join(f"at its {'maximum' if ext == max(steer[moving]) else 'minimum'} {ext:+.3g} rad for "
                        f"{100 * share:.0f}% of the moving time ({visits} times)" for ext, share, visits, _ in found)
    text = (f"steer sits {said}: a clip (the command's limit) or full lock. "
            "There the column no longer says what was asked, and the fit takes it for the road-wheel angle: "
            "right if the wheels stopped there too, wrong by what they turned beyond it if the clip is the "
            "logging's")
    if wheelbase:
        from stid.fit.plausibility import PLAUSIBLE_PER_RAD

        at_clip = [h for h in held_steer.slow_holds([run], wheelbase, PLAUSIBLE_PER_RAD)
                   if any(abs(h.steer - ext) <= tol for ext, *_ in found)]
        gain = held_steer.gain_of(at_clip, wheelbase, PLAUSIBLE_PER_RAD)
        if gain is not None:
            text += (f"; held there, slowly, the car turned {gain.gain:.2f} of it ({gain.words()}): "
                     + ("the wheels stop about where the column says" if not gain.far_from_one() else
                        "the wheels are not where the column says there"))
    return text + ". Drive inside the limit for identification where you can"


def _between_share(steer, moving, at_ext, tol, fs) -> float:
    """Share of the moving time at neither an extreme nor a level held for HELD_LEVEL_S."""
    held = np.zeros(len(steer), bool)
    flat = np.concatenate([[False], np.abs(np.diff(steer)) <= tol])
    for a, b in segments.runs_of(flat, max(int(HELD_LEVEL_S * fs), 1)):
        held[max(a - 1, 0):b] = True
    between = moving & ~held
    for at in at_ext:
        between &= ~at
    return float(between.sum() / max(moving.sum(), 1))
