"""Intervals that stay true when the model is not exactly the car.

The time-domain fit's standard errors (a Newey-West sandwich on the residuals) are
right about noise. They say nothing about model error: a model that is slightly
wrong gives estimates that move with the conditions of each piece of data (speed,
amplitude, which manoeuvre), and a noise-only interval then rarely contains the
truth. A delete-a-block jackknife sees that movement: the data are cut into K
contiguous blocks (whole seconds of driving, so the residuals' correlation stays
inside a block), the model is refitted K times with one block left out, and the
spread of those estimates is the parameter's variance under noise *and* the model
error that varies between blocks. Each refit is one Gauss-Newton step from the
full estimate with the block's rows removed from the Jacobian and residuals (the
linearised jackknife): leaving out an eighth of the data moves the estimate
little, so the step is the refit to first order, at no simulation cost.

The interval printed is the wider of the two, per parameter, with Student's t on
K - 1 degrees of freedom when the jackknife is the wider one; plus, where the data
show them, the distance to the exact-geometry answer and to the answer with the delay the
data show between the steer and the outputs (below): errors common to all the blocks,
which no jackknife or bootstrap can see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOCK_MIN_S = 4.0  # a block must outlast the residuals' correlation (~0.5 s) many times over
K_MAX = 8
K_MIN = 5  # fewer blocks give a variance too uncertain to be worth printing
# Data too short for K_MIN blocks of BLOCK_MIN_S (10-20 s of driving) still get K_MIN blocks, as
# long as each holds this much: four times the residuals' correlation. Without them such a fit
# printed noise-only intervals however far the model was from the data: a real 1:10 car's 13 s
# of driving (tests/test_real_log.py, ds4) gave Cr [9.5, 15.3] N/rad at fit ay 29%, and the same
# car 7 minutes later [6.6, 9.3]; with 5 blocks of about 2.3 s, [7.9, 18.3].
BLOCK_SHORT_S = 2.0


def row_blocks(n_samples: int, seconds: float, k_max: int = K_MAX):
    """Each residual row's block (two rows per sample, samples in order: contiguous time,
    stretch after stretch) and the number of blocks; (None, 0) when the data are too short
    for K_MIN blocks of BLOCK_SHORT_S."""
    K = int(min(k_max, seconds // BLOCK_MIN_S))
    if K < K_MIN and seconds >= K_MIN * BLOCK_SHORT_S:
        K = K_MIN
    if K < K_MIN:
        return None, 0
    block = np.minimum(np.arange(n_samples) * K // max(n_samples, 1), K - 1)
    return np.repeat(block, 2), K


def jackknife_cov(J: np.ndarray, r: np.ndarray, row_block, K: int) -> np.ndarray | None:
    """Delete-a-block jackknife covariance in the fit's own coordinates, linearised: J and
    r are the Jacobian and residuals at the optimum, ``row_block`` each row's block (0..K-1)."""
    if row_block is None or K < K_MIN:
        return None
    # each block's share of the normal equations, in one pass: a refit without block b solves
    # (H - H_b) step = -(g - g_b), a p x p system, not a least-squares problem on seven eighths
    # of the rows (a copy of them each); when that system is ill-conditioned (squaring the
    # Jacobian's condition loses digits) the rows themselves are solved, as before
    Hs = np.zeros((K, J.shape[1], J.shape[1]))
    gs = np.zeros((K, J.shape[1]))
    for b in range(K):
        rows = row_block == b
        Hs[b] = J[rows].T @ J[rows]
        gs[b] = J[rows].T @ r[rows]
    H, g = Hs.sum(axis=0), gs.sum(axis=0)
    xs = []
    for b in range(K):
        Hb = H - Hs[b]
        if np.linalg.cond(Hb) < 1e8:
            xs.append(np.linalg.solve(Hb, -(g - gs[b])))
            continue
        keep = row_block != b
        step, *_ = np.linalg.lstsq(J[keep], -r[keep], rcond=None)
        xs.append(step)
    xs = np.array(xs)
    d = xs - xs.mean(axis=0)
    return (K - 1) / K * (d.T @ d)


def combine(cov_noise: np.ndarray, cov_jack: np.ndarray | None):
    """Per parameter the wider of the two variances, keeping the noise covariance's
    correlations: (covariance, which parameters the jackknife widened)."""
    if cov_jack is None:
        return cov_noise, []
    vn = np.maximum(np.diag(cov_noise), 1e-300)
    vj = np.diag(cov_jack)
    scale = np.sqrt(np.maximum(vj / vn, 1.0))
    return cov_noise * np.outer(scale, scale), [i for i, s in enumerate(scale) if s > 1.0]


# -- an error common to all the data: the linear model's small-angle geometry -----------
#
# The jackknife's blocks are alike (each holds a few seconds of the same driving), so an
# error common to all of them is invisible to it. The one every car has: the linear
# single track takes the small-angle geometry. On a car the front force acts along the
# steered wheel (lateral part F cos delta) and slip angles are atan((vy + a r)/vx), not
# the ratio; at an RC car's steer angles that moves Cf and Cr by tenths of a percent,
# more than their noise. Two steps:
#
# - is it in the data? A probe for the family of errors symmetric in the steer: the
#   front force times (1 + kappa delta^2), its sensitivity at kappa = 0 the response to
#   Cf alpha_f delta^2 (one simulation), kappa fitted to first order with the others.
#   An exact linear bicycle shows kappa = 0; a car shows about -1/2 (cos delta).
# - how far does it move the answer? The exact geometry, linear tyres, at the estimate:
#   its outputs minus the model's (one pass: the correction is of second order in the
#   angles), and the one least-squares step that change asks of the parameters.
#
# Each interval grows by that step (it then holds both the linear model's answer and the
# exact geometry's) unless the data rule the geometry out: where kappa is significant
# (|z| > Z_SIGNIFICANT) the data show it; where kappa is within Z_SIGNIFICANT standard errors
# of the geometry's own value (KAPPA_GEOMETRY) they cannot tell it from a car's; only data that
# reject both, an exact linear bicycle's (kappa = 0 within its errors, -1/2 outside them), keep
# the linear model's intervals. Gating on significance alone left a car with a trim and sensor
# offsets (the parameters the probe is correlated with: kappa -0.19 +- 0.18) with Cf's interval
# [397.9, 398.5] for a truth of 400, where the step to the exact geometry's answer gives 399.9.

Z_SIGNIFICANT = 2.0
# "the data show" it, a claim about the car, at 99%: at 95% a trial's exactly linear cars were told
# so in 6 of 40 fits (|z| 2.0-2.8), 2 of them by chance alone. The allowance still grows from 95%.
Z_SHOWN = 2.576
KAPPA_GEOMETRY = -0.5  # cos(delta) = 1 - delta^2 / 2: well-determined cars show -0.45 to -0.47


def wheel_geometry(model, p: dict, st):
    """(road-wheel angle, (vy + a r)/vx, (vy - b r)/vx) per sample as the model's tyres see
    them: the angle after the model's steering chain (a trim, a servo's lag, a linkage's map),
    not the logged command (with a 1.4 deg trim the command's square made the probe below fire
    on the trim: z = -3.8 where the wheel's gives -1.1, and the change fell 15% short). The slip
    angles' arguments come from the lateral velocity and the rear slip angle: the model's yaw
    rate output is the gyro's, with its errors. At the samples the models are driven at
    (Stretch.simulation_input: a fine steer's, where the stretch has one)."""
    from stid.models.lpv import V_FLOOR

    steer, dt, vx = st.simulation_input()
    s = model.simulate(p, steer, dt, vx, outputs=("alpha_f", "alpha_r", "vy"), sensors=st.sensors)
    ctx = model.context(1.0)
    v = np.maximum(np.asarray(vx, float), V_FLOOR)  # the speed the simulator's matrices take
    x_r = -s[:, 1]
    r = (s[:, 2] - v * x_r) / ctx.b
    x_f = (s[:, 2] + ctx.a * r) / v
    return s[:, 0] + x_f, x_f, x_r


def geometry_responses(model, p: dict, st):
    """(probe, change) on a stretch, (n, 2) each:

    - probe: d(ay, r)/d(kappa) at kappa = 0, the response to the front-axle force
      Cf alpha_f delta^2 [N], delta the road-wheel angle;
    - change: the outputs with exact large-angle geometry (cos delta on the front force, atan
      slip angles) minus the model's, at the same parameters.

    Both are the measured outputs' response to axle force inputs: the simulator's outputs less
    its zero-input outputs, which are the model's sensor offsets (sensor_bias: the gyro's and the
    accelerometer's). With them in, the probe carried the offsets and the exact-geometry change
    did too, so a model with an offset had that offset's interval widened by the offset's own size.
    One wheel-angle simulation and one force simulator serve both (two of each took 10.8 ms
    on the demo's two stretches, this 3.3 ms, for every fit that prints intervals)."""
    d, x_f, x_r = wheel_geometry(model, p, st)  # x: the linear slip angles' arguments
    _, dt, vx = st.simulation_input()
    sim = model.simulator(p, vx, dt, ["ay", "r"], ["dFf", "dFr"], st.sensors)
    zeros = np.zeros(len(d))
    at_rest = sim(np.column_stack([zeros, zeros]))
    probe = sim(np.column_stack([p["Cf"] * (d - x_f) * d ** 2, zeros])) - at_rest
    dFf = p["Cf"] * ((d - np.arctan(x_f)) * np.cos(d) - (d - x_f))
    dFr = p["Cr"] * (x_r - np.arctan(x_r))
    change = sim(np.column_stack([dFf, dFr])) - at_rest
    return probe[::st.fine], change[::st.fine]


@dataclass
class GeometryCheck:
    """What the probe found: ``allowance`` per parameter in the fit's coordinates (zero where
    the data rule the geometry out), kappa and its standard error (nan where the parameters
    already move the outputs as the probe would), and why the intervals grew."""
    allowance: np.ndarray
    kappa: float
    se: float

    @property
    def z(self) -> float:
        return self.kappa / self.se if self.se > 0 else float("nan")

    @property
    def shown(self) -> bool:
        """kappa is significant at 99%: the data show a symmetric steer nonlinearity."""
        return bool(abs(self.z) > Z_SHOWN)

    def words(self) -> str:
        """Why the intervals grew, for the fit's interval note ('' when they did not)."""
        if not np.any(self.allowance > 0):
            return ""
        kappa = (f"kappa {self.kappa:+.2f} (std. error {self.se:.2f}, z = {self.z:.1f}), where cos delta "
                 f"gives {KAPPA_GEOMETRY:+.1f}")
        if self.shown and self.kappa < 0:
            return ("the data show the large-angle geometry the linear model leaves out (a front force that "
                    f"changes with the square of the steer, force x (1 + kappa delta^2): {kappa})")
        if self.shown:  # significant, but of the other sign: not the geometry itself
            return ("the data show a front force that changes with the square of the steer (force x (1 + kappa "
                    f"delta^2): {kappa}), of the opposite sign to the large-angle geometry: something the model "
                    "or the data leave out that the geometry's allowance may not cover (a linkage, or a speed "
                    "measured late or coarsely: wheel odometry at 30 Hz moved it so on exactly linear cars)")
        seen = ("the parameters move the outputs as it would" if not np.isfinite(self.se) else kappa)
        return ("the data cannot rule out the large-angle geometry every car has and the linear model leaves "
                f"out (a front force that changes with the square of the steer, force x (1 + kappa delta^2): {seen})")


def geometry_allowance(J: np.ndarray, r: np.ndarray, probe: np.ndarray, change: np.ndarray, cov_of) -> GeometryCheck:
    """The probe's verdict and each parameter's allowance (GeometryCheck). ``probe`` and
    ``change`` are residual rows (scaled as r); ``cov_of(J, r)`` the noise covariance of a
    fit with Jacobian J and residuals r."""
    from stid.fit.convergence import null_directions

    p = J.shape[1]
    if not np.any(probe):  # no steer at all: nothing to move
        return GeometryCheck(np.zeros(p), 0.0, float("inf"))
    Jaug = np.column_stack([J, probe])
    if "probe" in null_directions(Jaug, [str(i) for i in range(p)] + ["probe"]):
        # the parameters already move the outputs as the probe would: kappa has no standard error
        # (a z from the pseudo-inverse's zero would be a huge number that means nothing), and the
        # data cannot rule the geometry out
        kappa, se = float("nan"), float("nan")
    else:
        step, *_ = np.linalg.lstsq(Jaug, -r, rcond=None)
        cov = cov_of(Jaug, r + Jaug @ step)
        kappa, se = float(step[-1]), float(np.sqrt(max(cov[-1, -1], 1e-300)))
        if abs(kappa) <= Z_SIGNIFICANT * se < abs(kappa - KAPPA_GEOMETRY):  # an exact linear bicycle's data
            return GeometryCheck(np.zeros(p), kappa, se)
    shift, *_ = np.linalg.lstsq(J, -change, rcond=None)
    return GeometryCheck(np.abs(shift), kappa, se)


# A delay between the steer and the outputs that the model leaves out: a servo's or its driver's
# dead time (a ROS command is stamped when it is sent, the servo acts on its next frame), a
# command timed by its receive time. The yaw dynamics of a scale car settle in ~16 ms, and Iz is
# what sets that: a new user's exact single-track bags with 2 ms of dead time gave Iz +12.7% with
# an interval of +-1% (tests/test_ros_import.py: +8%), and `diagnose` found "nothing missing", a
# sensor_delay gaining under 0.25 fit points. Yet the data show such a delay to +-0.04 ms: the
# probe is the outputs' response to shifting the steer (one simulation), fitted to first order
# with the parameters. Where it is significant, each interval grows by how far the parameters
# move to fit the outputs with the steer delayed by the far end of the delay's 95% range
# (delay_allowance); where not, the intervals stay. The simulated car's right models read
# 0.01-0.07 ms (|z| up to 3): a little wider where that is significant.

DELAY_PROBE_MS = 1.0  # the probe's unit: a millisecond of delay


def delayed_change(model, p: dict, st, y0: np.ndarray, delay_s: float) -> np.ndarray:
    """The outputs at ``p`` with the steer ``delay_s`` later, less ``y0`` (the fit's outputs on the
    stretch, which it has already), on a stretch (the steer drawn with lines between samples, as
    the models take it; zero-input outputs, a sensor's offsets, cancel)."""
    steer, dt, vx = st.simulation_input()
    t = st.t if st.fine == 1 else st.t[0] + dt * np.arange(len(steer))
    later = np.interp(t - delay_s, t, steer)
    return model.simulate(p, later, dt, vx, sensors=st.sensors)[::st.fine] - y0


def delay_probe(model, p: dict, st, y0: np.ndarray) -> np.ndarray:
    """d(ay, r)/d(delay) [per ms] on a stretch (``y0``: the outputs at ``p``): over an eighth of a sample."""
    h = st.dt / 8
    return delayed_change(model, p, st, y0, h) * (DELAY_PROBE_MS * 1e-3 / h)


CHORD_STEPS = 3  # steps toward the answer with the delay (each one simulation per stretch)


@dataclass
class DelayCheck:
    """The delay the data show beyond the model's, in ms, its standard error, and each
    parameter's allowance in the fit's coordinates (zero unless the delay is significant)."""
    allowance: np.ndarray
    delay_ms: float
    se_ms: float

    @property
    def z(self) -> float:
        return self.delay_ms / self.se_ms if self.se_ms > 0 else float("nan")

    def words(self) -> str:
        """Why the intervals grew, for the fit's interval note ('' when they did not)."""
        if not np.any(self.allowance > 0):
            return ""
        seen = f"{abs(self.delay_ms):.2f} ms (std. error {self.se_ms:.2f}, z = {self.z:.0f})"
        if self.delay_ms > 0:
            return (f"the outputs answer the steer {seen} later than the model has them (a servo's lag or dead "
                    "time, a sensor's delay: `stid diagnose` names which; or a sensor filter declared faster or of "
                    "a lower order than it is: [sensors])")
        return (f"the outputs answer the steer {seen} earlier than the model has them: the steer is timed late (a "
                "command timed by its receive time, a logger's clock), or a sensor filter is declared slower or of "
                "a higher order than it is ([sensors])")


def delay_allowance(J: np.ndarray, r: np.ndarray, probe: np.ndarray, cov_of, change_at) -> DelayCheck:
    """The delay the data show (DelayCheck): ``probe`` residual rows (scaled as r) per ms of
    delay; ``cov_of(J, r)`` the noise covariance of a fit with Jacobian J and residuals r;
    ``change_at(ms, dx)`` the residual rows' change with the steer that much later and the
    parameters moved by ``dx`` (fit coordinates; delayed_change).

    The allowance is how far the parameters move to fit the outputs with the steer delayed by the
    far end of the delay's 95% range: CHORD_STEPS Gauss-Newton steps with the fit's Jacobian. The
    probe's first-order step fell short (the outputs' answer to a delay is not linear in it over a
    sample, nor the parameters'): a new user's 2 ms bag missed Iz by 1%, a 5 ms one by 3%."""
    from stid.fit.convergence import null_directions

    p = J.shape[1]
    Jaug = np.column_stack([J, probe])
    if not np.any(probe) or "probe" in null_directions(Jaug, [str(i) for i in range(p)] + ["probe"]):
        return DelayCheck(np.zeros(p), float("nan"), float("nan"))  # no steer, or a model with a delay of its own
    step, *_ = np.linalg.lstsq(Jaug, -r, rcond=None)
    cov = cov_of(Jaug, r + Jaug @ step)
    delay, se = float(step[-1]), float(np.sqrt(max(cov[-1, -1], 1e-300)))
    if abs(delay) <= Z_SIGNIFICANT * se:
        return DelayCheck(np.zeros(p), delay, se)
    far = delay + np.copysign(Z_SIGNIFICANT * se, delay)
    dx = np.zeros(p)
    first = None
    for _ in range(CHORD_STEPS):
        try:
            with np.errstate(all="ignore"):  # (a step far out: exp overflows; said by the finite check below)
                change = change_at(far, dx)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError):  # a step into a model that cannot be built
            break
        if not np.all(np.isfinite(change)):
            break
        step_dx, *_ = np.linalg.lstsq(J, -(r + change), rcond=None)
        if not np.all(np.isfinite(step_dx)):
            break
        first = step_dx if first is None else first
        if np.any(np.abs(dx + step_dx) > 3 * np.abs(first) + 1e-12):
            break  # steps that grow (a model far from the data, where the delay stands in for more): the first
        dx = dx + step_dx
    # (no chord step could be taken: the probe's first-order step)
    return DelayCheck(np.abs(dx if first is not None else step[:-1]), delay, se)


# -- an error common to a run: the gyro zero taken off its yaw rate -------------------------
#
# The loader takes the gyro's zero from the run's stand-still (stid.convert.gyro_zero_from_still),
# a mean of noise over a second or two: it is off by its own standard error, and that offset is
# in every r sample the fit sees. The noise covariance counts it nowhere. A parameter that a
# constant in r moves (a trim's delta0, a gyro's bias_r) came out of its interval by 4 standard
# errors on a trial user's trimmed car with 1.9 s of stand-still (its zero 0.0005 rad/s off).
ZERO_Z = 1.96  # the zero's own 95% range, whose far end the allowance holds


def gyro_zero_allowance(J: np.ndarray, stretches, keeps, sigma_r: float) -> np.ndarray:
    """Each parameter's move (fit coordinates, absolute) when each run's gyro zero is off by ZERO_Z of
    its standard error, the runs' independent moves added in quadrature; zeros without a zero
    taken. The residuals are the fit's: the kept samples of each stretch in turn, (ay, r) rows
    scaled by their levels (``sigma_r``: r's). One least-squares solve, no simulation: a
    constant in r is a column of the residuals' own."""
    p = J.shape[1]
    cols, ses, pos = {}, {}, 0
    for st, k in zip(stretches, keeps):
        m = int(np.sum(k))
        zero = getattr(st, "gyro_zero", None)
        se = float(zero.get("stderr", float("nan"))) if zero else float("nan")
        if np.isfinite(se) and se > 0:  # the stretches of one run share its zero (one record)
            col = cols.setdefault(id(zero), np.zeros(J.shape[0]))
            col[pos + 1:pos + 2 * m:2] = -1.0 / sigma_r
            ses[id(zero)] = se
        pos += 2 * m
    if not cols:
        return np.zeros(p)
    C = np.column_stack(list(cols.values()))
    with np.errstate(all="ignore"):
        shift, *_ = np.linalg.lstsq(J, -C, rcond=None)  # (p, runs): the move per rad/s of each run's zero
    out = ZERO_Z * np.sqrt(np.sum((shift * np.array(list(ses.values()))) ** 2, axis=1))
    return np.where(np.isfinite(out), out, 0.0)
