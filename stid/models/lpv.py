"""Simulating a linear model whose matrices depend on the forward speed, driven by
the measured speed vx(t): a linear parameter-varying (LPV) single track.

A track run accelerates and brakes; the single-track matrices hold vx and 1/vx
(slip angles, the centripetal term, relaxation rates), so a model at one median
speed is wrong wherever the speed is not that. Here every sample uses the
matrices at its own speed:

    x[k+1] = F(v_k) x[k] + (G1(v_k) - G2(v_k)) u[k] + G2(v_k) u[k+1]
    y[k]   = C(v_k) x[k] + D(v_k) u[k]

with the first-order-hold discretisation (the input is piecewise linear between
samples, as in the constant-speed simulator). Discretising at every sample would
cost a matrix exponential per sample, so the matrices are discretised on a
geometric grid of speeds 2% apart (GRID_STEP) and interpolated linearly between
grid points (the interpolation error is of order (2%)^2 / 8 of the speed dependence,
far below the noise). The continuous matrices at the grid speeds come from three builds of
the model: every entry of a single-track model with the catalogue's effects is of
the form c0 + c1 vx + c2 / vx, which three builds determine (once per parameter set:
every stretch of an evaluation shares the law; tests/test_effects_contract.py checks
the law for every catalogue effect). A model with a user's effect gets a fourth build
to check it, and where the check fails (another speed law) is built at every grid
speed instead: slower, never wrong.

The recursion itself is a compiled loop (stid.models.recursion: C where it was built, numba
otherwise): a time-varying system has no transfer function for scipy's filters, and a Python
loop per sample would cost a second per evaluation.
"""

from __future__ import annotations

import contextlib

import numpy as np
from scipy import linalg

from stid.models import recursion

# Relative spacing of the speed grid. At +-25% of speed swing the simulation differs from an
# ODE solver's by 3.4e-5 of the signal's rms at 2% (1.6e-5 at 1%: tests/test_track_runs.py),
# far below any sensor noise; the discretisation at the grid points is half the cost of a
# simulation, and a 2% grid halves it.
GRID_STEP = 0.02
V_FLOOR = 0.3  # m/s: the single track is not defined standing still; slower samples use this


_GRIDS: dict = {}  # speed series -> its grid: a fit simulates the same stretches hundreds of times


def speed_grid(vx: np.ndarray, step: float = GRID_STEP):
    """Grid speeds covering vx; for every sample the grid interval and the weight of its
    upper end, at the sample (outputs) and half a step later (the step's midpoint speed,
    which makes the time-varying recursion second-order accurate); and the lattice index
    of the first grid speed. The grid is a piece of one lattice, log v = k * step for every
    integer k, the same for every series: stretches whose speeds overlap share grid speeds,
    and so the discretisations at them (_NodeFoh)."""
    vx = np.ascontiguousarray(vx, float)
    key = (len(vx), step, hash(vx.tobytes()))
    hit = _GRIDS.get(key)
    if hit is None or not np.array_equal(hit[0], vx):  # a hash is not proof: compare
        if len(_GRIDS) >= 64:
            _GRIDS.pop(next(iter(_GRIDS)))
        hit = _GRIDS[key] = (vx.copy(), _speed_grid(vx, step))
    return hit[1]


def _speed_grid(vx: np.ndarray, step: float):
    v = np.maximum(np.asarray(vx, float), V_FLOOR)
    lv = np.log(v)
    k_lo = int(np.floor(lv.min() / step))
    n = max(2, int(np.ceil(lv.max() / step)) - k_lo + 1)
    lo = k_lo * step
    grid_l = step * (k_lo + np.arange(n))

    def locate(x):
        pos = np.clip((x - lo) / step, 0.0, n - 1.0)
        idx = np.minimum(np.floor(pos).astype(np.int64), n - 2)
        return idx, pos - idx

    idx, w = locate(lv)
    mid = np.log(0.5 * (v[:-1] + v[1:])) if len(v) > 1 else lv
    idx_s, w_s = locate(np.concatenate([mid, lv[-1:]]))
    return np.exp(grid_l), idx, w, idx_s, w_s, k_lo


def _batched_foh(A, B, dt):
    """First-order-hold matrices F, G1 - G2, G2 (see ``x[k+1]`` above) for a stack of
    systems A (L, n, n), B (L, n, m): closed forms in each system's eigenbasis, as
    ``linsys.foh`` (one batched eigendecomposition; scipy's expm costs milliseconds
    per matrix), with expm for any system that is not safely diagonalisable."""
    L, n, m = B.shape
    lam, V = np.linalg.eig(A)
    # condition number in the 1-norm from the inverse needed anyway (an SVD per matrix
    # cost more than the rest of the discretisation)
    with np.errstate(all="ignore"):
        try:
            Vinv = np.linalg.inv(V)
        except np.linalg.LinAlgError:  # one singular in the stack: the others keep their closed form
            Vinv = np.full(V.shape, np.nan, dtype=V.dtype)  # (as a stack of one system alone would)
            for i in range(L):
                with contextlib.suppress(np.linalg.LinAlgError):
                    Vinv[i] = np.linalg.inv(V[i])
        cond = np.abs(V).sum(axis=1).max(axis=1) * np.abs(Vinv).sum(axis=1).max(axis=1)
    good = np.isfinite(cond) & (cond < 1e8) & np.all(np.abs(lam) * dt > 1e-6, axis=1)
    F = np.empty((L, n, n))
    G1 = np.empty((L, n, m))
    G2 = np.empty((L, n, m))
    if good.any():
        lg, Vg = lam[good], V[good]
        Vi = Vinv[good]
        Bt = Vi @ B[good]
        z = lg * dt
        ez = np.exp(z)
        F[good] = ((Vg * ez[:, None, :]) @ Vi).real
        G1[good] = (Vg @ (((ez - 1) / lg)[:, :, None] * Bt)).real
        G2[good] = (Vg @ (((ez - 1 - z) / (lg * z))[:, :, None] * Bt)).real
    for i in np.flatnonzero(~good):
        M = np.zeros((n + 2 * m, n + 2 * m))
        M[:n, :n] = A[i] * dt
        M[:n, n:n + m] = B[i] * dt
        M[n:n + m, n + m:] = np.eye(m)
        E = linalg.expm(M)
        F[i], G1[i], G2[i] = E[:n, :n], E[:n, n:n + m], E[:n, n + m:]
    return F, G1 - G2, G2


# The discretised matrices are smooth in log speed: they are computed at every NODE_EVERY-th
# speed of the lattice (an 8% spacing) and the grid filled in between by cubic interpolation. On
# the catalogue's effects that fill is off by 1e-7 to 2e-6 of the largest entry, 6 to 100 times
# less than the linear interpolation between grid speeds the recursion does; against an ODE
# solver the simulation's error stays 3.4e-5 (tests/test_track_runs.py). A fourth of the
# eigendecompositions, and the nodes are shared by every stretch of an evaluation (_NodeFoh).
NODE_EVERY = 4
_FILLS: dict = {}


def _fill(k_lo: int, n: int):
    """((n, nodes) weights, first node, last node) filling the lattice speeds k_lo .. k_lo + n - 1
    from the lattice's nodes (every NODE_EVERY-th speed) by cubic Lagrange interpolation over
    the four nearest: two below a speed, two above (a speed on a node takes that node)."""
    key = (k_lo, n)
    hit = _FILLS.get(key)
    if hit is None:
        k = k_lo + np.arange(n)
        below = k // NODE_EVERY  # the node at or below each speed (floor division: also for k < 0)
        frac = (k - below * NODE_EVERY) / NODE_EVERY  # 0 <= frac < 1
        j_first, j_last = int(below[0]) - 1, int(below[-1]) + 2
        xs = np.arange(-1.0, 3.0)  # the four nodes' positions, in node spacings from `below`
        W = np.ones((n, 4))
        for a in range(4):
            for b in range(4):
                if b != a:
                    W[:, a] *= (frac - xs[b]) / (xs[a] - xs[b])
        fill = np.zeros((n, j_last - j_first + 1))  # as one matrix: the fill is one product
        np.put_along_axis(fill, (below - 1 - j_first)[:, None] + np.arange(4)[None, :], W, axis=1)
        if len(_FILLS) >= 256:
            _FILLS.pop(next(iter(_FILLS)))
        hit = _FILLS[key] = (fill, j_first, j_last)
    return hit


class _NodeFoh:
    """The first-order-hold matrices of one (A, B) speed law at one sample period, at the
    lattice's nodes, computed as stretches ask for them: every stretch of an evaluation
    simulates the same parameters, and a parameter that moves neither A nor B (a sensor's
    place, scale or offset: a column of the Jacobian) leaves them as they were (``_node_foh``
    finds them by the law's coefficients). ``hint``: the nodes the previous parameters'
    stretches asked for (a solver's next evaluation simulates the same stretches): computed
    at the first request, in one batched discretisation instead of one per stretch."""

    def __init__(self, law: "SpeedLaw", dt: float, hint=None):
        self.law, self.dt, self.hint = law, dt, hint
        # (node index of the first, (F, G0, G1) at nodes first .. first + len - 1), replaced whole:
        # a fit in another thread (a Dask worker's) that shares these parameters reads either the
        # old or the new, never one's index with the other's matrices
        self.held = None
        self.asked = None  # (first, last) node of every request so far

    def at(self, j_first: int, j_last: int):
        return _nodes_of_many([self], j_first, j_last, self.dt)[0]

    def missing(self, j_first: int, j_last: int) -> list:
        """The node ranges (first, last) a request for j_first .. j_last needs computed (the hint's
        too, at the first request)."""
        self.asked = (j_first, j_last) if self.asked is None else (min(self.asked[0], j_first),
                                                                   max(self.asked[1], j_last))
        held = self.held
        if held is None:
            return [(j_first, j_last) if self.hint is None else (min(self.hint[0], j_first),
                                                                  max(self.hint[1], j_last))]
        first, mats = held
        last = first + len(mats[0]) - 1
        return [r for r in ((j_first, first - 1), (last + 1, j_last)) if r[0] <= r[1]]

    def put(self, pieces: list, computed: list) -> None:
        """Take in the matrices ``computed`` at the node ranges ``pieces`` (from ``missing``)."""
        held = self.held
        for (a, b), mats_new in sorted(zip(pieces, computed), key=lambda pc: pc[0][0]):
            if held is None:
                held = (a, tuple(mats_new))
                continue
            first, mats = held
            last = first + len(mats[0]) - 1
            if b == first - 1:
                held = (a, tuple(np.concatenate([x, y]) for x, y in zip(mats_new, mats)))
            elif a == last + 1:
                held = (first, tuple(np.concatenate([x, y]) for x, y in zip(mats, mats_new)))
            elif not (first <= a and b <= last):  # (another thread's put came between: start anew)
                held = (a, tuple(mats_new))
        self.held = held

    def slice(self, j_first: int, j_last: int):
        first, mats = self.held
        a = j_first - first
        if a < 0 or j_last - first >= len(mats[0]):  # (another thread's put came between)
            return self._compute(j_first, j_last)
        return tuple(m[a:a + j_last - j_first + 1] for m in mats)

    def _compute(self, j_first: int, j_last: int):
        A, B = self.law.at(node_speeds(j_first, j_last), parts=2)
        return _batched_foh(A, B, self.dt)


def node_speeds(j_first: int, j_last: int) -> np.ndarray:
    return np.exp(GRID_STEP * NODE_EVERY * np.arange(j_first, j_last + 1))


def _nodes_of_many(node_fohs: list, j_first: int, j_last: int, dt: float) -> list:
    """``[nf.at(j_first, j_last) for nf in node_fohs]``, with every node any of them lacks
    discretised in one batch: a Jacobian's columns are as many parameter sets, each with
    its own A and B, and one batched eigendecomposition costs little more than one."""
    jobs, seen = [], set()
    for nf in node_fohs:
        if id(nf) not in seen:
            seen.add(id(nf))
            pieces = nf.missing(j_first, j_last)
            if pieces:
                jobs.append((nf, pieces))
    if jobs:
        laws = [nf.law.at(node_speeds(a, b), parts=2) for nf, pieces in jobs for a, b in pieces]
        mats = _batched_foh(np.concatenate([A for A, _ in laws]), np.concatenate([B for _, B in laws]), dt)
        ends = np.cumsum([len(A) for A, _ in laws])[:-1]
        per_piece = list(zip(*(np.split(m, ends) for m in mats)))
        i = 0
        for nf, pieces in jobs:
            nf.put(pieces, per_piece[i:i + len(pieces)])
            i += len(pieces)
    return [nf.slice(j_first, j_last) for nf in node_fohs]


_NODE_FOH: dict = {}  # (dt, the A and B law's coefficients) -> _NodeFoh, newest last


def _node_foh(law: "SpeedLaw", dt: float) -> _NodeFoh:
    key = (float(dt), law.coef[:, :law._ends[1]].tobytes())
    hit = _NODE_FOH.pop(key, None)
    if hit is None:
        newest = next(reversed(_NODE_FOH.values()), None)
        hit = _NodeFoh(law, dt, hint=newest.asked if newest is not None and newest.dt == dt else None)
        if len(_NODE_FOH) >= 16:  # the parameter vectors of a Jacobian and the point it is taken at
            _NODE_FOH.pop(next(iter(_NODE_FOH)))
    _NODE_FOH[key] = hit
    return hit


PROBE_SPEEDS = (1.0, 3.0, 9.0, 4.7)  # m/s: three determine the speed law, the fourth checks it


class SpeedLaw:
    """The matrices of ``build(v)`` as c0 + c1 v + c2 / v, from builds at PROBE_SPEEDS.

    One law serves every stretch (and every speed) of an evaluation: the parameters
    are the same, only the speeds differ. ``ok`` is False when the fourth build does
    not follow the law (a user's effect with another speed law); then each stretch
    builds at its own grid speeds. ``check=False`` trusts the law without the fourth
    build: for the catalogue's effects, whose law tests/test_effects_contract.py checks
    (a build is most of the Python work of a simulation)."""

    _V_INV = np.linalg.inv(np.column_stack([np.ones(3), np.asarray(PROBE_SPEEDS[:3]),
                                            1.0 / np.asarray(PROBE_SPEEDS[:3])]))

    def __init__(self, parts, check: bool = True):
        built = [parts(v) for v in PROBE_SPEEDS[:4 if check else 3]]
        self.shapes = [b.shape for b in built[0]]
        self._ends = np.cumsum([b.size for b in built[0]])[:-1]
        # every entry of every matrix in one row per build: one product finds all the laws
        X = np.stack([np.concatenate([b.ravel() for b in bs]) for bs in built])
        c = self._V_INV @ X[:3]  # (c0, c1, c2) of every entry
        self.coef = c
        if check:  # each matrix at the fourth speed, to 1e-9 of its own size
            v4 = PROBE_SPEEDS[3]
            off = np.split(np.abs(c[0] + c[1] * v4 + c[2] / v4 - X[3]), self._ends)
            size = np.split(np.abs(X[:3]), self._ends, axis=1)
            if any(np.max(d, initial=0.0) > 1e-9 * max(float(np.max(x, initial=0.0)), 1e-300)
                   for d, x in zip(off, size)):
                self.coef = None
        self.ok = self.coef is not None

    def at(self, grid: np.ndarray, parts: int = 5) -> list:
        """The first ``parts`` matrices (A, B, C, D, offsets) at each grid speed."""
        g = np.asarray(grid, float)[:, None]
        c = self.coef[:, :self._ends[parts - 1]] if parts < len(self.shapes) else self.coef
        flat = c[0][None] + c[1][None] * g + c[2][None] / g
        return [a.reshape((len(g),) + shape) for a, shape in zip(np.split(flat, self._ends[:parts - 1], axis=1),
                                                                  self.shapes[:parts])]


def system_parts(build, outputs, inputs):
    """``parts(v) -> (A, B, C, D, offsets)`` of ``build(v)`` restricted to the named
    outputs and inputs."""
    outs, ins = list(outputs), list(inputs)

    def parts(v):
        s = build(float(v))
        io = [s.out(o) for o in outs]
        ii = [s.inp(i) for i in ins]
        return (s.A, s.B[:, ii], s.C[io], s.D[io][:, ii], np.array([s.offsets.get(o, 0.0) for o in outs]))

    return parts


class LpvSimulator:
    """``sim(u) -> y`` for a model built at every speed by ``build(v) -> LinSys``.

    Parameters
    ----------
    build : callable
        Speed [m/s] -> LinSys with inputs/outputs named as in ``inputs``/``outputs``.
    vx : ndarray
        Forward speed at each sample [m/s].
    dt : float
        Sample period [s].
    law : SpeedLaw, optional
        The speed law of ``build`` when the caller has it already (the same parameters
        simulated on several stretches): saves the probe builds.
    """

    def __init__(self, build, vx, dt: float, outputs, inputs, law: SpeedLaw | None = None):
        grid, self.idx, self.w, self.idx_s, self.w_s, k_lo = speed_grid(vx)
        self.n_t = len(self.idx)
        parts = system_parts(build, outputs, inputs)
        if law is None:
            law = SpeedLaw(parts)
        fill, j_first, j_last = _fill(k_lo, len(grid))
        if law.ok:
            stacks = law.at(grid)
            nodes = _node_foh(law, dt).at(j_first, j_last)
        else:  # an effect with another speed law: built at every grid speed and node
            every = [parts(v) for v in grid]
            stacks = [np.stack([e[j] for e in every]) for j in range(5)]
            at_nodes = [parts(v) for v in node_speeds(j_first, j_last)]
            nodes = _batched_foh(np.stack([e[0] for e in at_nodes]), np.stack([e[1] for e in at_nodes]), dt)
        F, G0, G1 = ((fill @ M.reshape(len(M), -1)).reshape((len(grid),) + M.shape[1:]) for M in nodes)
        self._take(stacks, F, G0, G1)

    @classmethod
    def many(cls, laws: list, vx, dt: float) -> list:
        """``[LpvSimulator(build, vx, dt, ..., law=law) for law in laws]`` for laws that all hold
        (``law.ok``) and share their matrices' shapes (one model's parameter sets: a Jacobian's
        columns): the nodes of all are discretised in one batch, and filled in one product."""
        grid, idx, w, idx_s, w_s, k_lo = speed_grid(vx)
        fill, j_first, j_last = _fill(k_lo, len(grid))
        nodes = _nodes_of_many([_node_foh(law, dt) for law in laws], j_first, j_last, dt)
        # (S, nodes, n, .) -> one product with the fill for every system
        F, G0, G1 = ((fill @ M.reshape(M.shape[0], M.shape[1], -1)).reshape((len(laws), len(grid)) + M.shape[2:])
                     for M in (np.stack(m) for m in zip(*nodes)))
        sims = []
        for k, law in enumerate(laws):
            sim = cls.__new__(cls)
            sim.idx, sim.w, sim.idx_s, sim.w_s, sim.n_t = idx, w, idx_s, w_s, len(idx)
            sim._take(law.at(grid), F[k], G0[k], G1[k])
            sims.append(sim)
        return sims

    def _take(self, stacks, F, G0, G1) -> None:
        A, B, C, D, off = stacks
        # C-ordered, as the compiled recursion was cached for (another layout compiles anew)
        self.F, self.G0, self.G1, self.C, self.D, self.off = (np.ascontiguousarray(a) for a in (F, G0, G1, C, D, off))
        # steady state at the first sample's speed for a unit input on each channel
        a0 = self.w[0]
        A0 = (1 - a0) * A[self.idx[0]] + a0 * A[self.idx[0] + 1]
        B0 = (1 - a0) * B[self.idx[0]] + a0 * B[self.idx[0] + 1]
        try:
            self.x_unit = -np.linalg.solve(A0, B0)  # (n, m)
        except np.linalg.LinAlgError:  # a pole at zero (no steady state): start at rest
            self.x_unit = np.zeros_like(B0)

    def __call__(self, u: np.ndarray, u_out: np.ndarray | None = None) -> np.ndarray:
        """Outputs for inputs u (n_t, m) or (n_t,). ``u_out``: other samples of the same
        inputs for the direct feedthrough D u (the states take u, the held input; an
        output without dynamics in between takes the sample itself, linsys.foh_input)."""
        u = self._shape(u)
        uo = u if u_out is None else self._shape(u_out)
        x0 = self.x_unit @ u[0]
        return recursion.ltv_run(self.F, self.G0, self.G1, self.C, self.D, self.off, self.idx, self.w,
                                 self.idx_s, self.w_s, u, uo, x0)

    def _shape(self, u) -> np.ndarray:
        u = np.asarray(u, float)
        if u.ndim == 1:
            u = u[:, None]
        if len(u) != self.n_t:
            raise ValueError(f"input has {len(u)} samples, the speed series {self.n_t}")
        return np.ascontiguousarray(u)
