"""The noise floor: an estimate of the fit percent a *correct* model reaches on this
data (the part of ay and r the measured steer, at the measured speed, cannot
explain: sensor noise, vibration), so the user knows when to stop adding effects.

It is estimated without any vehicle model: a long FIR predictor (1 s of steer
history and a constant) is fitted by least squares to four fifths of the data
and scored on the fifth left out, five times (cross-validation keeps it from
counting noise as signal). Two things kept the first version of this estimate
below what a correct model reaches, so a correct model "beat the floor":

- the car's response changes with speed, and even a "constant" 4 m/s run swings by
  a few percent (ay ~ vx r): one impulse response cannot follow that. The taps vary
  with the speed, d = v/median(v) - 1, both where the speed scales the response
  (the output's time: h_j(1 + c1 d + c2 d^2)) and where it scales the input (the
  steer's time: FIR of steer*d and steer*d^2), the frozen-speed response of a
  slowly varying car to second order;
- a predictor with p taps trained on n samples carries its own estimation error
  into the score: out of sample it adds to the noise's mean square about as much as it
  takes away from the errors on the samples it was trained on (both tr(H Sigma) / n,
  H its hat matrix and Sigma the noise's covariance, whatever the noise's colour). The
  floor is scored on the geometric mean of the two mean squares.

A steer trim (an offset the log's steer lacks, whose response moves with the speed) and the
tyres' first departure from linear (the steer's cube through a short FIR) are in the predictor
too: without them the floor sat below what the right model reaches, so a fit of the wrong
model that far short was not told it missed something (ay, floor before -> now, right model:
a trim at a swinging speed, plain physics 83.8 -> 99.3%, 99.3%; the simulator's trim with a
gyro offset 93.3 -> 99.4%, 99.2%; its saturating tyres 95.8 -> 98.7%, 99.6%; tanh tyres at 5.7
deg of steer, plain physics, 88.0 -> 96.0%, 99.4%: tests/test_noise_floor.py). What it still
cannot predict (noise, and a nonlinearity that follows the slip rather than the steer, as a
tyre deep in its saturation) no model of that family can; such an effect may beat it.
``noise_floor_uncertainty`` is the delete-a-fold jackknife's standard error of the
floor: a model above the floor by more than about twice that is a sign the
estimator is wrong. Samples lost on the link are neither trained on nor scored."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import cho_factor, cho_solve, toeplitz

from stid.stats import SCORE_FROM_S

MEMORY_S = SCORE_FROM_S  # 1 s of steer history; scored where every model is scored
CUBIC_SHARE = 4  # the cube's FIR is a quarter of the steer's memory (longer gained nothing: ts and ts2 runs)
FOLDS = 5
OUTS = ("ay", "r")


def _fir_columns(u: np.ndarray, taps: int) -> np.ndarray:
    row = np.zeros(taps)
    row[0] = u[0]
    return toeplitz(u, row)


def _design(u: np.ndarray, vx, taps: int, v_ref: float) -> np.ndarray:
    # the steer itself, not its deviation from the mean: the response to the mean steer
    # changes with the speed too, and a centred input would leave it out
    u0 = np.asarray(u, float)
    base = _fir_columns(u0, taps)
    cols = [base]
    if vx is not None:
        d = np.asarray(vx, float) / v_ref - 1.0
        for k in (1, 2):
            cols.append(base * (d ** k)[:, None])  # speed at the output's time
            cols.append(_fir_columns(u0 * d ** k, taps))  # speed at the steer's time
            # a constant the log's steer does not carry (a servo trim) answers as the car does at the
            # speed: an offset that moves with it (a gyro's or accelerometer's own offset is the
            # constant), through the car's dynamics as the speed changes: a short FIR. (As the speed
            # alone, the floor sat 0.5 points below the right model on a trim at a swinging speed
            # once the estimation error was no longer over-corrected, below; 0.02 points with it)
            cols.append(_fir_columns(d ** k, max(2, taps // CUBIC_SHARE)))
    # the cube of the steer through a short FIR: the tyres' first departure from linear (a car that
    # nears its grip). Without it the floor sat below what the right model reaches on a car whose
    # tyres saturate (ay 95.8% where bicycle+tyre_saturation fits 99.6%), and a fit of the wrong
    # model, short of it by ~4 points, was not told so
    cols.append(_fir_columns(u0 ** 3, max(2, taps // CUBIC_SHARE)))
    return np.column_stack(cols + [np.ones(len(u))])


def floor_errors(stretches, memory_s: float = MEMORY_S, keep_from_s: float = 0.5, with_folds: bool = False,
                 ridge: float = 1e-6, known=None):
    """The predictor's cross-validated errors (the floor, sample by sample) and the outputs
    they belong to, per output: lists of arrays, one per stretch (and, ``with_folds``, each
    sample's fold).

    One predictor per run (the speed law is expanded about the run's own median speed; a run
    that holds two separate speeds: one per speed, evidence.speed_pieces), cross-validated over
    FOLDS contiguous blocks of the run's stretches laid end to end, so the short stretches of a
    run cut where the car slowed count too.

    The result is kept on ``stretches`` (diagnose, compare and the report ask for the same
    floor of the same stretches several times; each costs a few Cholesky factors of ~500²).
    ``known``: the result, computed elsewhere (a worker: ``submit_floor``), to keep."""
    key = (memory_s, keep_from_s, with_folds, ridge)
    cache = getattr(stretches, "_floor_cache", None) or {}
    if key in cache:
        return cache[key]
    folded = cache.get((memory_s, keep_from_s, True, ridge))
    if folded is not None:  # the same errors, kept with their folds
        return folded[:2]
    out = known if known is not None else _floor_errors(stretches, memory_s, keep_from_s, with_folds, ridge)
    try:
        stretches._floor_cache = {**cache, key: out}
    except AttributeError:  # a plain list: nothing to keep it on
        pass
    return out


def submit_floor(pool, stretches):
    """``noise_floor_uncertainty(stretches)`` computed in a worker of ``pool``: a Future of
    (floor, its standard error). The errors behind it come back with it and are kept on
    ``stretches``, where the residual analyses of diagnose and the report ask for them again
    (0.15 s each time they are computed)."""
    from concurrent.futures import Future

    out = Future()
    out.set_running_or_notify_cancel()  # (not cancellable itself: the worker's job is)

    def done(job):
        try:
            errors = floor_errors(stretches, with_folds=True, known=job.result())
        except BaseException as e:  # (the pool torn down under it: whoever waits hears why)
            out.set_exception(e)
            return
        out.set_result(_floor_from(errors))

    pool.submit(_folded_errors, stretches).add_done_callback(done)
    return out


def _folded_errors(stretches):
    return floor_errors(stretches, with_folds=True)


# The predictor's rate. The fit runs at 200 Hz; the data are prefiltered at 20 Hz, so every
# other sample carries the same information, and the FIR's size (and its Cholesky factors,
# ~p^3) would grow 2x (8x) for nothing. Its fit percent is the same population's.
FLOOR_FS = 100.0


def floor_rate(stretches) -> float:
    """The sample rate of ``floor_errors``' arrays [Hz] (the stretches', thinned to ~FLOOR_FS)."""
    dt = stretches[0].dt
    return 1.0 / (dt * max(1, int(round(1.0 / (FLOOR_FS * dt)))))


def _thinned(stretches):
    out = []
    for st in stretches:
        q = max(1, int(round(1.0 / (FLOOR_FS * st.dt))))
        if q == 1 or len(st.t) < 4 * q:
            out.append(st)
            continue
        # the phase that keeps the most measured samples: a log missing every other row (a slower
        # channel) thinned from its first sample had kept none, and the predictor was fitted on nothing
        phase = 0 if st.valid is None else int(np.argmax([np.count_nonzero(st.valid[k::q]) for k in range(q)]))
        out.append(st.cut(phase, None, q))
    return out


def _floor_errors(stretches, memory_s, keep_from_s, with_folds, ridge):
    from stid.analysis.evidence import speed_pieces

    # a run that holds two speeds is predicted at each on its own (its pieces there: each its own
    # predictor, the change between them left out): the speed law about one median speed cannot
    # span 3 to 6 m/s, and a trial user's two-speed runs had floors 1-2.4 points below what the
    # right model reached, +-1.1 to 1.6 (+-0.05 at one speed)
    # (a run's stretches share its predictor: "run.csv[2]" is the run's; a piece is its speed's)
    whole = {id(st) for st in stretches}
    pieces = speed_pieces(stretches)
    keys = [st.name.split("[")[0] + ("" if id(st) in whole else f" at {st.vx:.1f} m/s") for st in pieces]
    err = {o: [] for o in OUTS}
    ref = {o: [] for o in OUTS}
    folds = []
    groups: dict = {}
    for key, st in zip(keys, _thinned(pieces)):
        groups.setdefault(key, []).append(st)
    for items in groups.values():
        e, r, f = _run_errors(items, memory_s, keep_from_s, ridge)
        for o in OUTS:
            err[o].extend(e[o])
            ref[o].extend(r[o])
        folds.extend(f)
    return (err, ref, folds) if with_folds else (err, ref)


def _run_errors(items, memory_s, keep_from_s, ridge):
    taps = max(5, int(round(memory_s / items[0].dt)))
    items = [st for st in items if len(st.steer) > taps + 10]
    err = {o: [] for o in OUTS}
    ref = {o: [] for o in OUTS}
    folds = []
    if not items or sum(len(st.steer) for st in items) < 8 * taps:
        return err, ref, folds
    speeds = [np.asarray(st.vx_series, float) for st in items if getattr(st, "vx_series", None) is not None]
    v_ref = float(np.median(np.concatenate(speeds))) if speeds else 1.0
    total = sum(len(st.steer) for st in items)
    edges = np.linspace(0, total, FOLDS + 1)

    def rows(st, start):
        X = _design(st.steer, getattr(st, "vx_series", None), taps, v_ref)
        Y = np.column_stack([st.ay, st.r])
        valid = getattr(st, "valid", None)
        use = np.ones(len(st.t), bool) if valid is None else np.asarray(valid, bool).copy()
        keep = use & ((st.t - st.t[0]) >= max(keep_from_s, memory_s))
        use[:taps] = False  # the FIR's history is not data yet
        fold = np.minimum(np.searchsorted(edges, start + np.arange(len(st.t)), side="right") - 1, FOLDS - 1)
        return X, Y, use, keep, fold

    Gf = Bf = Yf = None
    nf = np.zeros(FOLDS)
    start = 0
    built = []  # the design of each stretch, kept for scoring (building it costs as much as using it)
    for st in items:
        X, Y, use, keep, fold = rows(st, start)
        built.append((X, Y, keep, fold))
        start += len(st.steer)
        if Gf is None:
            p = X.shape[1]
            Gf, Bf, Yf = np.zeros((FOLDS, p, p)), np.zeros((FOLDS, p, 2)), np.zeros((FOLDS, 2))
        for k in range(FOLDS):
            m = use & (fold == k)
            if m.any():
                Gf[k] += X[m].T @ X[m]
                Bf[k] += X[m].T @ Y[m]
                Yf[k] += np.sum(Y[m] ** 2, axis=0)
                nf[k] += m.sum()
    G, B, YY = Gf.sum(axis=0), Bf.sum(axis=0), Yf.sum(axis=0)  # the folds partition the used rows
    p = G.shape[0]
    W, sse_in = [], np.zeros(2)
    for k in range(FOLDS):
        Gk, Bk = G - Gf[k], B - Bf[k]
        lam = ridge * np.trace(Gk) / p
        c = cho_factor(Gk + lam * np.eye(p), check_finite=False)
        Wk = cho_solve(c, Bk, check_finite=False)
        W.append(Wk)
        # the predictor's squared errors on the rows it was trained on, from the sums (y - X w)^2 =
        # y'y - 2 w'X'y + w'X'X w: no second pass over the data
        sse_in += (YY - Yf[k]) - 2 * np.sum(Wk * Bk, axis=0) + np.sum(Wk * (Gk @ Wk), axis=0)
    mse_in = np.maximum(sse_in, 0.0) / max(float(FOLDS - 1) * nf.sum(), 1.0)  # (each row trains FOLDS - 1 folds)
    raw, keeps, fold_of = [], [], []
    for X, Y, keep, fold in built:
        E = np.empty_like(Y)
        for k in range(FOLDS):
            m = fold == k
            E[m] = Y[m] - X[m] @ W[k]
        raw.append((E, Y))
        keeps.append(keep)
        fold_of.append(fold)
    # The predictor's own estimation error: out of sample it adds to the noise's mean square as much
    # as it takes away in sample (both are tr(H Sigma) / n, H the hat matrix, Sigma the noise's
    # covariance: to first order, whatever the noise's colour). Their geometric mean is the noise's
    # (exactly, for least squares on Gaussian regressors and white noise: in sample sigma^2 (1 - p/n),
    # out of sample sigma^2 / (1 - p/n); on a trial's short runs it came 0.1 points nearer the right
    # model than the mean of the two).
    # (The first version divided the out-of-sample errors by sqrt(1 + p tau / n), with tau the noise's
    # integrated autocorrelation time: right for white noise, but with coloured noise the estimation
    # error follows tau_noise x tau_steer summed over lags, far less than tau_noise alone: on 12 s
    # runs with noise below 1 Hz the floor read 1.6 points above the right model's fit, and 6 of
    # 30 such fits were told they were far below it.)
    scored = np.concatenate([E[k] for (E, _), k in zip(raw, keeps)])
    mse_out = np.mean(scored ** 2, axis=0) if len(scored) else np.ones(2)
    shrink = np.clip(mse_in / np.maximum(mse_out, 1e-300), 0.0, 1.0) ** 0.25  # (on the errors: mse ** 0.5)
    for (E, Y), keep, fold in zip(raw, keeps, fold_of):
        E *= shrink
        for j, name in enumerate(OUTS):
            err[name].append(E[keep, j])
            ref[name].append(Y[keep, j])
        folds.append(fold[keep])
    return err, ref, folds


def _percent(e: np.ndarray, y: np.ndarray) -> float:
    return float(100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean())))


# A floor whose standard error exceeds this many fit points says nothing about what a model
# should reach: the data do not determine it (too little steering across frequencies for the
# predictor). It is then not given (nan, as for stretches too short), with its standard error.
UNDETERMINED_SE = 5.0


def noise_floor_uncertainty(stretches, memory_s: float = MEMORY_S, keep_from_s: float = 0.5):
    """(floor, its standard error) per output, in fit points."""
    return _floor_from(floor_errors(stretches, memory_s, keep_from_s, with_folds=True))


def _floor_from(errors):
    err, ref, folds = errors
    floor, se = {}, {}
    for o in OUTS:
        if not err[o]:
            floor[o], se[o] = float("nan"), float("nan")
            continue
        e, y, f = np.concatenate(err[o]), np.concatenate(ref[o]), np.concatenate(folds)
        floor[o] = _percent(e, y)
        jk = np.array([_percent(e[f != k], y[f != k]) for k in range(FOLDS)])
        se[o] = float(np.sqrt((FOLDS - 1) / FOLDS * np.sum((jk - jk.mean()) ** 2)))
        if se[o] > UNDETERMINED_SE:  # (a circle at constant steer: 68% +- 28 where the bicycle fits 99.5%)
            floor[o] = float("nan")
    return floor, se


def noise_floor(stretches, memory_s: float = MEMORY_S, keep_from_s: float = 0.5) -> dict:
    return noise_floor_uncertainty(stretches, memory_s, keep_from_s)[0]


def below_floor(res, floor, se) -> dict:
    """Per output, how many fit points the model is short of the noise floor, where that is more
    than chance (2.576 standard errors of the floor) and 2 points: its intervals then hold only
    if the model were right."""
    return {o: round(floor[o] - res.fit[o], 2) for o in floor
            if o in res.fit and np.isfinite(floor[o]) and floor[o] - res.fit[o] > max(2.0, 2.576 * se.get(o, 0.0))}


def gyro_zero_points(res, stretches, z: float = 3.0) -> dict:
    """Fit points of r a right model may sit below the floor because of the gyro zero taken off r at
    load ({} where none was): the floor's predictor has a constant, the model has none, so the
    zero's own error (``z`` of its standard errors, the kinematics' rule 3 allowance without the
    drift) costs the model and not the floor. From the fit's r residual (1 - fit / 100 of r's
    spread) and the offset delta: 100 (sqrt((1 - fit / 100)^2 + delta^2 / var r) - (1 - fit / 100)).
    A trial's right fits on 12-40 s runs with noise below 1 Hz lay up to 1.2 points below the
    floor in r at 8 of the floor's standard errors, all of it the zero (0.012 rad/s off after
    1.8 s of stand-still)."""
    zeros = [getattr(s, "gyro_zero", None) for s in stretches or []]
    zeros = [zz for zz in zeros if zz and np.isfinite(zz.get("stderr", np.nan))]
    if not zeros or "r" not in res.fit or not res.predictions:
        return {}
    r = np.concatenate([pr.y[pr.keep, 1] for pr in res.predictions])
    var = float(np.var(r)) if len(r) > 1 else 0.0
    if not var > 0:
        return {}
    delta = z * max(zz["stderr"] for zz in zeros)
    miss = max(1.0 - res.fit["r"] / 100.0, 0.0)
    return {"r": float(100.0 * (np.sqrt(miss ** 2 + delta ** 2 / var) - miss))}


SMALL_GAP = 0.5  # fit points: a gap smaller than this is not worth a sentence (as above_floor's)


def below_floor_small(res, floor, se, allowance: dict | None = None) -> dict:
    """Per output, fit points short of the floor that are more than chance (2.576 standard errors of
    the floor, plus ``allowance``: what a known error outside the model costs it, gyro_zero_points)
    and half a point, but not far (below_floor's 2 points): a small effect may be missing, which
    ``stid diagnose`` looks for. A trial's accelerometer 5 cm ahead of the CG left the bicycle 1.0-1.9
    points below the floor in ay at 4-65 standard errors, and `stid fit` said nothing in 28 of 40 runs
    (diagnose named it in each run tried); on right fits of the same cases no ay gap was beyond chance."""
    far = below_floor(res, floor, se)
    out = {}
    for o in floor:
        if o in far or o not in res.fit or not np.isfinite(floor[o]):
            continue
        gap = floor[o] - res.fit[o]
        if gap > max(SMALL_GAP, 2.576 * se.get(o, 0.0) + (allowance or {}).get(o, 0.0)):
            out[o] = round(gap, 2)
    return out


def runs_below_floor(res, runs) -> dict:
    """below_floor of a fit ``res`` against the noise floor of the runs it was fitted to ({} where
    they hold nothing to estimate one from): `stid plan` and `stid batch` judge their fits so."""
    from stid.errors import StidError
    from stid.fit import dataset

    if not res.predictions:
        return {}
    try:
        floor, se = noise_floor_uncertainty(dataset.dynamic_stretches(runs))
    except StidError:
        return {}
    return below_floor(res, floor, se)


def above_floor(fit: dict, floor, se) -> dict:
    """Per output, how many fit points a model is above the noise floor, where that is more than
    chance (2.576 standard errors of the floor) and half a point: then the floor is no reference.
    It misses something this data holds that a model reaches: a nonlinearity that follows the
    slip rather than the steer, as tyres deep in their saturation (the simulated car's fit ay 98.5%
    with bicycle+tyre_saturation where the floor read 94.7% +- 0.96)."""
    return {o: round(fit[o] - floor[o], 2) for o in floor
            if o in fit and np.isfinite(floor[o]) and fit[o] - floor[o] > max(0.5, 2.576 * se.get(o, 0.0))}


ABOVE_WORDS = ("the floor misses a nonlinearity this data holds (such as tyres deep in their saturation): it is "
               "no reference for what is left here")


def floor_words(floor: dict, se: dict | None = None, fit: dict | None = None) -> str:
    """The noise floor per output, or why an output has none (``se``: its standard errors;
    ``fit``: a model's fit percent, which the floor should not be below)."""
    known = [o for o, v in floor.items() if math.isfinite(v)]
    wide = {o: (se or {})[o] for o in floor if o not in known and math.isfinite((se or {}).get(o, math.nan))}
    parts = []
    above = above_floor(fit, floor, se or {}) if fit else {}
    if known and above:
        parts.append("noise floor " + ", ".join(f"{o} {floor[o]:.1f}%" for o in known)
                     + f" (the model fits above it in {', '.join(above)}: {ABOVE_WORDS})")
    elif known:
        parts.append("noise floor " + ", ".join(f"{o} {floor[o]:.1f}%" for o in known)
                     + " (what a correct model reaches here)")
    if wide:
        parts.append(("" if parts else "noise floor: ") + ", ".join(wide) + " not determined by this data "
                     "(standard error " + ", ".join(f"{s:.0f}" for s in wide.values()) + " points): it needs "
                     "steering across frequencies, such as random steer, not only circles or steps")
    rest = [o for o in floor if o not in known and o not in wide]
    if rest:  # (alone, it is the whole floor: no outputs named)
        parts.append((", ".join(rest) + " " if parts else "noise floor: ") + "not estimated (the stretches are "
                     "too short for its 1 s predictor in 5 folds; log longer runs)")
    return "; ".join(parts)
