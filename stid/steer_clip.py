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
# A chosen step steer (0, +-A) spends almost no time off its levels; a clipped command spends
# a share of its time between (FrictionMaps: 22-30%). Between: at neither an extreme nor the
# commonest other value.
MIN_BETWEEN_SHARE = 0.10
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
    if not found or _between_share(steer, moving, [f[3] for f in found], tol) < MIN_BETWEEN_SHARE:
        return ""
    said = " and ".join(f"at its {'maximum' if ext == max(steer[moving]) else 'minimum'} {ext:+.3g} rad for "
                        f"{100 * share:.0f}% of the moving time ({visits} times)" for ext, share, visits, _ in found)
    text = (f"steer sits {said}: a clip (the command's limit) or full lock. "
            "There the column no longer says what was asked, and the fit takes it for the road-wheel angle: "
            "right if the wheels stopped there too, wrong by what they turned beyond it if the clip is the "
            "logging's")
    if wheelbase:
        text += _where_the_wheels_were(run, wheelbase, [ext for ext, *_ in found], tol)
    return text + ". Drive inside the limit for identification where you can"


# Held at the clip and held inside it, at the same speeds, linear tyres turn the car by the same
# share of the steer; the large angle at the clip adds up to ~5% (tan 0.35 rad = 1.04 x 0.35)
# and the tyres' first nonlinearity in gentle cornering about as much.
SAME_GAIN = 0.10


def _where_the_wheels_were(run, wheelbase, extremes, tol) -> str:
    """What the car's held steer says about the wheels at the clip: its gain there against its
    gain held inside the clip (linear tyres give both the same), else against what tyres allow
    at that speed."""
    from stid.fit.plausibility import PLAUSIBLE_PER_RAD

    holds = held_steer.slow_holds([run], wheelbase, PLAUSIBLE_PER_RAD)
    at_clip = [h for h in holds if any(abs(h.steer - ext) <= tol for ext in extremes)]
    inside = [h for h in holds if h not in at_clip]
    g_clip = held_steer.gain_of(at_clip, wheelbase, PLAUSIBLE_PER_RAD)
    if g_clip is None:
        return ""
    g_in = held_steer.gain_of(inside, wheelbase, PLAUSIBLE_PER_RAD)
    said = f"; held there, slowly, the car turned {g_clip.gain:.2f} of it ({g_clip.words()})"
    if g_in is not None:
        se = np.hypot(*(g.se if np.isfinite(g.se) else 0.0 for g in (g_clip, g_in)))
        apart = abs(g_clip.gain / g_in.gain - 1.0) > SAME_GAIN + 2 * se / g_in.gain
        said += f", and {g_in.gain:.2f} of the steer held inside the clip"
        return said + (": the wheels are not where the column says at the clip" if apart else
                       ": the wheels stop about where the column says")
    return said + (": the wheels are not where the column says there" if g_clip.far_from_one() else
                   ": the wheels stop about where the column says")


def _between_share(steer, moving, at_ext, tol) -> float:
    """Share of the moving time at neither an extreme nor the commonest other value (a step
    steer's centre, where it rests between its steps)."""
    between = moving.copy()
    for at in at_ext:
        between &= ~at
    if not between.any():
        return 0.0
    levels = np.round(steer[between] / tol).astype(np.int64)
    values, counts = np.unique(levels, return_counts=True)
    rest = between.sum() - counts.max()
    return float(rest / max(moving.sum(), 1))
