"""Time-domain output-error fit over several stretches: the measured steer drives
the model, and the simulated ay and r are matched to the measured ones.

The start of each stretch (``discard_s``) is left out of the cost, so the
unknown initial state does not bias the parameters; the model starts in the
steady state of the first steer sample. Outputs are weighted by the inverse of
their residual level at the answer (refined in rounds until the answer is stationary at
its own levels), which is the maximum-likelihood weighting for Gaussian errors of unknown
size per output.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import stdtrit  # Student t quantile (scipy.stats is slow to import)

from stid.fit.dataset import Stretch, check_excitation
from stid.fit.result import FitResult, Prediction, fit_percent
from stid.fit.solver import ParamSpace, starting_points, covariance_sandwich, least_squares, to_physical
from stid.errors import InputError
from stid.fit import checks, convergence
from stid.fit import intervals as jk
from stid.stats import SCORE_FROM_S, tau_int_blocks

OUTPUTS = ("ay", "r")


def _keep(st: Stretch, discard_s: float) -> np.ndarray:
    keep = (st.t - st.t[0]) >= discard_s
    return keep if st.valid is None else keep & st.valid


def _as_slice(keep: np.ndarray):
    """The kept samples as a slice where they are one run (as they are unless samples are
    invalid): a view, where a boolean mask copies (the copy was ~9% of an evaluation)."""
    kept = np.flatnonzero(keep)
    if len(kept) and kept[-1] - kept[0] + 1 == len(kept):
        return slice(int(kept[0]), int(kept[-1]) + 1)
    return keep


def simulate(model, p: dict, st: Stretch) -> np.ndarray:
    """The model driven by the stretch's steer at its measured speed (varying or not), at the
    stretch's samples (driven by a fine steer where it has one: Stretch.simulation_input)."""
    steer, dt, vx = st.simulation_input()
    y = model.simulate(p, steer, dt, vx, sensors=st.sensors)
    return y if st.fine == 1 else np.ascontiguousarray(y[::st.fine])


def simulate_many(model, ps: list, st: Stretch) -> list:
    """``[simulate(model, p, st) for p in ps]``, in one batch where the model can (Model.simulate_many)."""
    steer, dt, vx = st.simulation_input()
    ys = model.simulate_many(ps, steer, dt, vx, sensors=st.sensors) if len(ps) > 1 else \
        [model.simulate(ps[0], steer, dt, vx, sensors=st.sensors)]
    return ys if st.fine == 1 else [np.ascontiguousarray(y[::st.fine]) for y in ys]


# A long record (its stretches together: every run of the fit) is fitted in two steps: a sample of
# it first (COARSE_S of driving in pieces of PIECE_S drawn across it: coarse_sample), then the whole
# from that sample's answer. Near the optimum of a model that misses an effect the solver closes in
# only linearly (its residuals are large), and the step still to go must fall below a tenth of a
# standard error (convergence.STEP_SE_STOP), which shrinks as the record grows: so a record 16
# times as long took 1.4 times the evaluations on the whole of it (the bench's 40 s runs tiled 16
# times: 22 Jacobians where they took 16), and a model with effects three starts of them. From the
# sample's answer the whole takes a few.
# The answer is the whole record's optimum by the same rule either way (a sample only moves where
# the solve starts).
COARSE_S = 80.0  # s: a sample as long as the two 40 s runs a fit is made for
PIECE_S = 20.0  # s: long beside the 0.5 s each piece leaves out at its start, short enough to spread
COARSE_FROM = 3.0  # a record this many times COARSE_S is fitted on a sample first (at 2x it gained nothing)


def coarse_sample(stretches: list[Stretch]) -> list[Stretch] | None:
    """COARSE_S of the stretches in pieces of about PIECE_S, one piece drawn from each of
    COARSE_S / PIECE_S equal shares of the record's pieces in turn (spread over the record; drawn,
    not every k-th, so a lap driven again and again is not sampled at one place of it), or None
    when the record is shorter than COARSE_FROM times COARSE_S. The draw is seeded: the same
    record gives the same sample."""
    total = sum(len(st.t) * st.dt for st in stretches)
    if total < COARSE_FROM * COARSE_S:
        return None
    pieces = []
    for st in stretches:
        n = len(st.t)
        edges = np.linspace(0, n, max(1, round(n * st.dt / PIECE_S)) + 1).astype(int)
        pieces += [(st, int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    draw = np.random.default_rng(0)
    chosen = [int(draw.choice(share)) for share in np.array_split(np.arange(len(pieces)), round(COARSE_S / PIECE_S))]
    return [st.cut(a, b) for st, a, b in (pieces[i] for i in chosen)]


def fit_time(model, stretches: list[Stretch], fixed: dict | None = None, init: dict | None = None,
             discard_s: float = 0.5, multistart: bool | None = None, space: ParamSpace | None = None,
             method_name: str = "time", reweight: bool = True, sigma=None,
             whiten: bool = False, intervals: str = "noise", settle: bool = False) -> FitResult:
    """Output-error fit. ``intervals``: ``"noise"`` (Newey-West sandwich: right about
    noise) or ``"model-error"`` (also a delete-a-block jackknife, stid.fit.intervals: the
    wider of the two, for results a user reads). ``sigma``: each output's weight, held fixed
    (else they are found: the likelihood's, see _at_maximum_likelihood). ``settle`` (with
    ``init`` from a fit to most of the same data, as ``stid live`` refits while a run grows, or to
    a sample of them, as a long record is fitted: coarse_sample):
    the weighted solves start there, without the first solve that finds the neighbourhood."""
    fixed = dict(fixed or {})
    if not settle and reweight and sigma is None:
        sample = coarse_sample(stretches)
        if sample is not None:
            # a long record: its optimum's neighbourhood is found on a sample of it (the multistart, the
            # first weights), and the whole settles from there (coarse_sample)
            try:
                rough = fit_time(model, sample, fixed, init, discard_s, multistart, space, method_name,
                                 intervals="noise")
            except InputError:  # (a sample a fit cannot start from: the whole is fitted from the start)
                rough = None
            if rough is not None and np.all(np.isfinite(rough.values)):
                whole = fit_time(model, stretches, fixed, rough.all_params(), discard_s, False, space, method_name,
                                 whiten=whiten, intervals=intervals, settle=True)
                # (the solver's words count the whole record's evaluations: where the rest were spent)
                seconds = sum(len(st.t) * st.dt for st in sample)
                whole.status += (f"; started where the fit of a sample of the record ({seconds:.0f} s of it) ended "
                                 f"({rough.extra['evaluations']} evaluations on it)")
                return whole
    warnings = check_excitation(stretches)
    keeps = [_keep(s, discard_s) for s in stretches]
    ys = [s.y[k] for s, k in zip(stretches, keeps)]
    if sigma is None:
        sigma = np.std(np.vstack(ys), axis=0)
    else:
        reweight = False  # the caller fixes the weights (a candidate compared with its base)
    sigma = np.where(np.asarray(sigma) > 0, sigma, 1.0)

    ends = np.cumsum([int(k.sum()) for k in keeps])
    picks = [_as_slice(k) for k in keeps]

    def residual(p, sig):
        return residuals([p], sig)[0]

    def residuals(ps, sig):
        # written into one array each (hundreds of evaluations per fit): (n, 2) rows of every
        # stretch's kept samples in turn, each output divided by its sigma; the parameter sets
        # of a Jacobian's columns simulated together, stretch by stretch (Model.simulate_many)
        outs = [np.empty((int(ends[-1]) if len(ends) else 0, 2)) for _ in ps]
        for st, k, y, a, b in zip(stretches, picks, ys, np.r_[0, ends[:-1]], ends):
            for out, y_sim in zip(outs, simulate_many(model, ps, st)):
                np.subtract(y_sim[k], y, out=out[a:b])
        for out in outs:
            out /= sig
        return [out.ravel() for out in outs]

    if space is None:
        free = [n for n in model.param_names if n not in fixed]
        space = ParamSpace(model, free, fixed)
    p0 = model.defaults()
    p0.update(init or {})
    p0.update(fixed)
    if multistart is None:
        multistart = bool(model.effects)
    starts = starting_points(model, space, p0, multistart)
    if settle:
        # the start is the optimum of most of the same data: the solve starts there, weighted by
        # the residual levels it leaves (its residuals are known, so the first evaluation is free)
        r_start = residual(starts[0], np.ones(2)).reshape(-1, 2)
        sigma = _levels(r_start)
        res = least_squares(lambda p, s=sigma: residual(p, s), space, starts[:1], unit_noise=True,
                            many=lambda ps, s=sigma: residuals(ps, s),
                            known=(space.to_x(starts[0]), (r_start / sigma).ravel(), None),
                            colour=_colour(r_start, keeps, stretches[0].dt))
    else:
        # when the weights are refined below, this first solve only has to find them (to a
        # fraction of a percent): a loose tolerance saves most of its iterations, which creep
        # linearly on a model that misses an effect
        res = least_squares(lambda p, s=sigma: residual(p, s), space, starts, many=lambda ps, s=sigma: residuals(ps, s),
                            **({"ftol": 1e-4} if reweight else {}))
    if reweight or settle:
        res, sigma, colour = _at_maximum_likelihood(
            res, sigma, space,
            lambda s, known, colour: least_squares(lambda p: residual(p, s), space, [space.to_p(known[0])],
                                                   unit_noise=True, known=known, colour=colour,
                                                   many=lambda ps: residuals(ps, s)),
            lambda r: _colour(r, keeps, stretches[0].dt),
            lambda x, r, colour: _concentrated(lambda ps: [f.reshape(-1, 2) for f in residuals(ps, np.ones(2))],
                                               space, x, r,
                                               colour))
    p_hat = space.to_p(res.x)
    if whiten:
        # prediction-error refinement: an AR model of each output's residual colour, then
        # the residuals (and so the Jacobian) are whitened by its inverse: maximum
        # likelihood for Gaussian coloured noise, hence efficient
        from scipy import signal  # only here: scipy.signal is slow to import (stid.fit.filters)

        ar = _ar_models([simulate(model, p_hat, st)[k] - y for st, k, y in zip(stretches, keeps, ys)])

        def white_residual(p):
            out = []
            for st, k, y in zip(stretches, keeps, ys):
                e = simulate(model, p, st)[k] - y
                out.append(np.column_stack([signal.lfilter(ar[j][0], [1.0], e[:, j]) / ar[j][1]
                                            for j in range(2)])[AR_ORDER:].ravel())
            return np.concatenate(out)

        res = least_squares(white_residual, space, [p_hat], unit_noise=True)
        p_hat = space.to_p(res.x)
        keeps = [k.copy() for k in keeps]
        for k in keeps:  # the first AR_ORDER kept samples only warm the whitening filter up
            idx = np.flatnonzero(k)[:AR_ORDER]
            k[idx] = False

    cov = to_physical(_sandwich(res.jac, res.fun, keeps), space, res.x)
    preds, settled = [], True
    for st, k in zip(stretches, keeps):
        preds.append(Prediction(st.name, st.t, st.steer, st.y, simulate(model, p_hat, st), st.vx, k))
        settled = settled and model.converged  # an iterated tyre force settled on every stretch
    if whiten or not (reweight or settle):  # (else the rounds measured it where they ended)
        colour = _colour(res.fun.reshape(-1, 2), keeps, stretches[0].dt)
    verdict = convergence.judge(res, space, colour, settled)
    interval_note = "95% intervals: noise only (Newey-West sandwich on the residuals)"
    widened, jk_dof, allowance, result_delay, zero = [], None, None, None, None
    if intervals == "model-error" and verdict.converged:
        seconds = sum(int(k.sum()) * st.dt for st, k in zip(stretches, keeps))
        row_block, n_blocks = jk.row_blocks(len(res.fun) // 2, seconds)
        cov_jx = jk.jackknife_cov(res.jac, res.fun, row_block, n_blocks)
        if cov_jx is None:
            interval_note += f"; too little data for a model-error interval (needs {jk.K_MIN} blocks of " \
                             f"{jk.BLOCK_SHORT_S:g} s)"
        else:
            cov, widened = jk.combine(cov, to_physical(cov_jx, space, res.x))
            jk_dof = n_blocks - 1
            interval_note = (f"95% intervals: the wider of noise (Newey-West) and model error (delete-a-block "
                             f"jackknife, {n_blocks} blocks)"
                             + (f"; model error widened {', '.join(space.free[i] for i in widened)} "
                                f"(t with {jk_dof} dof)" if widened else ""))
        # a symmetric steer nonlinearity the linear model lacks (see stid.fit.intervals)
        rows = [jk.geometry_responses(model, p_hat, st) for st in stretches]
        probe, change = (np.concatenate([(r[j][k] / sigma).ravel() for r, k in zip(rows, keeps)]) for j in (0, 1))
        geometry = jk.geometry_allowance(res.jac, res.fun, probe, change, lambda J, r: _sandwich(J, r, keeps))
        allowance = geometry.allowance * space.dp_dx(res.x)  # to physical units (first order)
        grown = [n for n, a in zip(space.free, allowance) if a > 0 and n not in verdict.undetermined]
        if grown:
            interval_note += (f"; {geometry.words()}: {', '.join(grown)} widened to hold the answer with exact "
                              "geometry (cos delta, atan slip angles) too")
        # the gyro zero taken off r at load is off by its own standard error (see stid.fit.intervals)
        zero = jk.gyro_zero_allowance(res.jac, stretches, keeps, float(sigma[1])) * np.abs(space.dp_dx(res.x))
        half = stdtrit(jk_dof or max(len(res.fun) - len(res.x), 1), 0.975) * np.sqrt(np.maximum(np.diag(cov), 0.0))
        grown = [n for n, z, h in zip(space.free, zero, half) if z > 0.1 * h and n not in verdict.undetermined]
        if grown:
            interval_note += (f"; the gyro zero taken from the stand-still is itself uncertain: {', '.join(grown)} "
                              "widened to hold that too")
        # a delay between the steer and the outputs that the model leaves out (see stid.fit.intervals)
        # (each stretch's outputs at the estimate are its prediction's: not simulated again)
        probe = np.concatenate([(jk.delay_probe(model, p_hat, st, pr.yhat)[k] / sigma).ravel()
                                for st, k, pr in zip(stretches, keeps, preds)])
        delay = jk.delay_allowance(
            res.jac, res.fun, probe, lambda J, r: _sandwich(J, r, keeps),
            lambda ms, dx: np.concatenate([(jk.delayed_change(model, space.to_p(res.x + dx), st, pr.yhat,
                                                              ms * 1e-3)[k] / sigma).ravel()
                                           for st, k, pr in zip(stretches, keeps, preds)]))
        late = delay.allowance * space.dp_dx(res.x)
        grown = [n for n, a in zip(space.free, late) if a > 0 and n not in verdict.undetermined]
        if grown:
            interval_note += f"; {delay.words()}: {', '.join(grown)} widened to hold the answer with that delay"
        result_delay = delay

    result = make_result(model, method_name, space, p_hat, cov, preds, sigma)
    result.set_verdict(verdict)
    result.extra["evaluations"] = int(res.nfev)
    result.extra["sigma"] = np.asarray(sigma, float)
    result.interval = interval_note
    if widened:
        result.ci_dof = jk_dof
        result.extra["jackknife_widened"] = [space.free[i] for i in widened]
    if allowance is not None and np.any(allowance > 0):
        result.ci_allowance = allowance
    if zero is not None and np.any(zero > 0):
        result.zero_allowance = zero
    if result_delay is not None and np.isfinite(result_delay.delay_ms):
        result.extra["delay_seen_ms"] = (result_delay.delay_ms, result_delay.se_ms)
        if np.any(late > 0):
            result.delay_allowance = late
    for w in warnings:
        result.warn(w)
    for note in getattr(stretches, "notes", []):
        result.note(note)
    for n in space.at_bound(res.x):
        if model.at_vanishing_end(n, p_hat[n]):
            # (a servo lag of 1e-06 s on a car without one is the truth, not a push beyond the range: a trial
            # user was told the model lacks an effect)
            result.note(f"{n} sits at the end of its range where its effect vanishes ({p_hat[n]:.4g} "
                        f"{model.param(n).unit}): the data show none of it")
            continue
        result.warn(f"{n} stopped at its bound ({p_hat[n]:.4g} {model.param(n).unit}): the data push it "
                    "outside the plausible range, or the model lacks an effect")
    checks.add_identifiability_warnings(result, model, stretches)
    return result


# Rounds of re-weighting a fit may take to reach the likelihood's weights. Each round leaves the
# next a smaller change (on the bench's 5-minute track run, fitted without its servo lag: the
# yaw-rate level 0.062 -> 0.039 -> 0.033 -> 0.0326 rad/s), so a handful is what it takes where the
# model is near the data. A model far from them trades one output's fit for the other's along a
# nearly flat likelihood, where each round moved the levels' ratio by ~3% (a trial user's car with
# a trim, a servo lag and an offset accelerometer, fitted as bicycle+steer_offset: 0.49 -> 0.89 in
# ten rounds, its optimum at 3.0). The fit then ended "not converged", and its candidate counted
# for nothing in a diagnosis; on a shorter piece of the same run the rounds stopped, each moving
# the parameters too little to go on, where the likelihood curves down: no optimum, called one.
# From ACCELERATE_FROM rounds on, the likelihood with the levels set by the parameters is solved
# for at once (_concentrated), and the rounds go on from its optimum.
MAX_WEIGHT_ROUNDS = 10
ACCELERATE_FROM = 3


def _levels(r: np.ndarray) -> np.ndarray:
    """Each output's residual level (root mean square) in unweighted residuals r (n, 2): the
    weights that maximise the likelihood of zero-mean Gaussian errors at that point (what the
    cost, sum (r / sigma)^2, measures: an offset of the residuals counts as error)."""
    sigma = np.sqrt(np.mean(r * r, axis=0))
    return np.where(sigma > 0, sigma, 1.0)


def _at_maximum_likelihood(res, sigma, space: ParamSpace, solve, colour_of, concentrated=None):
    """Gaussian errors of an unknown size per output: the likelihood's optimum weights each
    output by the residual level the optimum leaves. So the weights are refined: each round
    weights the residuals by the levels the last solve left and solves again from where it
    ended (``solve(sigma, known, colour)``), until the answer is stationary at its own weights
    by the rule that ends a solve (convergence.STEP_SE_STOP). A round weighted by the levels
    the last one left raises the likelihood (the parameters' best for the levels, then the
    levels' best for the parameters), so those rounds converge; the first round's levels are
    foreseen instead (_levels_ahead: most of the way at once). A fit refined once only (as
    stid fit was) can end standard errors away when the model misses an effect and the levels
    move far from the first ones.

    ``res``: a solve weighted by ``sigma``; ``colour_of(r)``: the integrated autocorrelation
    time of unweighted residuals r (n, 2); ``concentrated(x, r, colour)``: the likelihood's optimum
    with the levels set by the parameters, from x with unweighted residuals r (_concentrated:
    ``(x, r, evaluations)``), where the rounds creep (ACCELERATE_FROM). Returns the last solve, its residuals and Jacobian
    re-weighted by its own levels (what the verdict and the intervals are taken from; its
    evaluations counted over every round), those levels, and the residuals' colour there."""
    lo, hi = space.bounds_x()
    nfev, rounds, jumped = 0, 0, False
    while True:
        nfev += res.nfev
        r = res.fun.reshape(-1, 2) * sigma  # unweighted
        Ju = res.jac.reshape(-1, 2, res.jac.shape[1]) * sigma[None, :, None]
        own = _levels(r)
        f, J = (r / own).ravel(), (Ju / own[None, :, None]).reshape(res.jac.shape)
        colour = colour_of(r)
        step = convergence.remaining_step(J, f, res.x, lo, hi, colour)
        if rounds == MAX_WEIGHT_ROUNDS or step < convergence.STEP_SE_STOP:
            # (the last solve stopped at its own weights; the levels it left are others: said so)
            res.weights_settled = step < convergence.STEP_SE_STOP
            break
        sigma = own
        if rounds >= ACCELERATE_FROM and not jumped and concentrated is not None:  # the rounds creep
            jumped = True
            x, r, spent = concentrated(res.x, r, colour)
            nfev += spent
            sigma = _levels(r)
            res = solve(sigma, (x, (r / sigma).ravel(), None), colour)
            rounds += 1
            continue
        if rounds == 0:  # foreseen once; then each round's own levels, which always converge
            held = space.at_bound(res.x)
            inside = [i for i, n in enumerate(space.free) if n not in held]
            if inside:
                sigma = _levels_ahead(r, Ju[:, :, inside], own)
        res = solve(sigma, (res.x, (r / sigma).ravel(),
                            np.asfortranarray((Ju / sigma[None, :, None]).reshape(res.jac.shape))), colour)
        rounds += 1
    res.fun, res.jac, res.nfev = f, J, nfev
    return res, own, colour


def _concentrated(unweighted, space: ParamSpace, x0, r0, colour: float):
    """The optimum of the likelihood of Gaussian errors of unknown size per output with those sizes
    set by the parameters themselves (each its output's residual level: the product of the two
    outputs' sums of squares is minimised), from ``x0``, in one bounded least-squares solve: the
    residuals of each output times the other's root sum of squares. Where re-weighted solves creep
    along a nearly flat likelihood (the parameters trading one output's fit for the other's), this
    follows the likelihood itself. ``unweighted(ps)``: the residuals (n, 2) of each parameter set;
    ``r0``: theirs at x0.
    Returns the optimum x, its residuals (n, 2) and the evaluations spent."""
    ss0 = np.maximum(np.sum(r0 * r0, axis=0), 1e-300)
    scale = np.sqrt(2.0 * ss0[0] * ss0[1] / len(r0))  # (fixed: unit-noise-sized residuals at the start)

    def of(r):
        ss = np.sum(r * r, axis=0)
        return np.concatenate([np.sqrt(ss[1]) * r[:, 0], np.sqrt(ss[0]) * r[:, 1]]) / scale

    res = least_squares(lambda p: of(unweighted([p])[0]), space, [space.to_p(x0)], unit_noise=True, colour=colour,
                        known=(np.asarray(x0, float), of(r0), None), many=lambda ps: [of(r) for r in unweighted(ps)])
    return res.x, unweighted([space.to_p(res.x)])[0], res.nfev + 1


def _levels_ahead(r: np.ndarray, Ju: np.ndarray, own: np.ndarray) -> np.ndarray:
    """The residual levels at the likelihood's optimum as the Jacobian foresees them: the
    re-weighting rounds run to their end on the linearised residuals r + Ju s (p x p sums, no
    simulation), so a round's solve is weighted by where the weights are going, not by where
    they are (re-weighted by its own levels only, a solve moves the weights a fraction of the way
    each round: the slow part of the loop). ``own`` when the linearisation gives nothing usable.
    r: (n, 2) unweighted residuals; Ju: (n, 2, p) their Jacobian in the parameters free to move
    (one at a bound would be foreseen beyond it)."""
    H = np.einsum("nop,noq->opq", Ju, Ju)
    g = np.einsum("nop,no->op", Ju, r)
    c = np.einsum("no,no->o", r, r)
    ss = c.copy()
    for _ in range(50):
        w = 1.0 / ss
        try:
            step = -np.linalg.solve(np.einsum("o,opq->pq", w, H), w @ g)
        except np.linalg.LinAlgError:
            return own
        new = c + 2.0 * g @ step + np.einsum("p,opq,q->o", step, H, step)
        if not (np.all(np.isfinite(new)) and np.all(new > 0)):
            return own
        done = np.allclose(new, ss, rtol=1e-6)
        ss = new
        if done:
            break
    return np.sqrt(ss / len(r))


AR_ORDER = 12


def _colour(r: np.ndarray, keeps: list, dt: float, max_lag_s: float = 0.5) -> float:
    """The residuals' integrated autocorrelation time [samples], the whiter output's (the
    smaller: the stricter stopping rule), as stid.analysis.residuals measures it. ``r``:
    (n, 2), the kept samples of every stretch in turn."""
    blocks = np.split(r, np.cumsum([int(k.sum()) for k in keeps])[:-1])
    taus = tau_int_blocks(blocks, max(2, int(max_lag_s / dt)))
    return float(taus.min()) if taus.size and taus.min() > 0 else 1.0


def _sandwich(J: np.ndarray, r: np.ndarray, keeps: list) -> np.ndarray:
    """Newey-West covariance of a fit whose residual rows are the kept samples of each
    stretch in turn, two outputs per sample."""
    J_blocks, r_blocks, pos = [], [], 0
    for k in keeps:
        m = int(k.sum()) * 2
        J_blocks.append(J[pos:pos + m].reshape(-1, 2, J.shape[1]))
        r_blocks.append(r[pos:pos + m].reshape(-1, 2))
        pos += m
    return covariance_sandwich(J_blocks, r_blocks)


def _ar_models(residual_blocks, order: int = AR_ORDER):
    """Per output: (whitening filter a, innovation std) of an AR model by Yule-Walker."""
    from scipy.linalg import solve_toeplitz

    out = []
    for j in range(2):
        e = np.concatenate([b[:, j] - b[:, j].mean() for b in residual_blocks])
        n = len(e)
        f = np.fft.rfft(e, 2 * n)
        ac = np.fft.irfft(f * np.conj(f))[: order + 1] / n
        phi = solve_toeplitz(ac[:order], ac[1:order + 1])
        a = np.concatenate([[1.0], -phi])
        s2 = max(ac[0] - phi @ ac[1:order + 1], 1e-30 * ac[0])
        out.append((a, float(np.sqrt(s2))))
    return out


def make_result(model, method: str, space: ParamSpace, p_hat: dict, cov: np.ndarray, preds: list,
                sigma=None) -> FitResult:
    names = list(space.free)
    values = np.array([p_hat[n] for n in names])
    fixed = {n: (p_hat[n], model.param(n).unit, "held fixed") for n in space.fixed}
    result = FitResult(model=model.name, method=method, names=names, values=values, cov=cov,
                       units={n: model.param(n).unit for n in model.param_names},
                       owners={n: model.owner(n) for n in model.param_names}, fixed=fixed, predictions=preds,
                       positive=tuple(n for n in names if model.param(n).log))
    fill_fit_stats(result, preds)
    return result


def fill_fit_stats(result: FitResult, preds: list) -> None:
    """Fit percent per output (scored from SCORE_FROM_S into each stretch, the noise floor's
    samples) and the Gaussian log-likelihood over the kept samples (the cost's)."""
    scored = [p.keep & ((p.t - p.t[0]) >= SCORE_FROM_S) for p in preds]
    if sum(int(k.sum()) for k in scored) < 10:  # stretches too short to score late: score all kept
        scored = [p.keep for p in preds]
    ys = np.vstack([p.y[k] for p, k in zip(preds, scored)])
    yhs = np.vstack([p.yhat[k] for p, k in zip(preds, scored)])
    result.fit = {o: fit_percent(ys[:, i], yhs[:, i]) for i, o in enumerate(OUTPUTS)}
    y = np.vstack([p.y[p.keep] for p in preds])
    yh = np.vstack([p.yhat[p.keep] for p in preds])
    e = y - yh
    n = len(e)
    var = np.maximum(np.mean(e ** 2, axis=0), 1e-300)
    result.n = 2 * n
    result.loglik = float(-0.5 * n * np.sum(np.log(2 * math.pi * var) + 1))
