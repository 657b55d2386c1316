"""The LPV recursion compiled by numba (stid.models.recursion takes it where the C build of the
same loop, stid/models/ltv_recursion.c, is not there). Imported only then: numba's import and
its cache's load cost a cold command 0.18 s."""

from __future__ import annotations

import contextlib

import numpy as np
from numba import njit


# reassociation lets the compiler reorder the short sums of the recursion (6-15% faster in
# alternating runs; round-off differs by ~1e-15 of the signal). Not the other fast-math flags:
# a diverging parameter set must still give inf/nan, which the optimiser steers away from.
@njit(cache=True, fastmath={"reassoc"})
def _ltv_run(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0):  # pragma: no cover (compiled)
    n_t = u.shape[0]
    n_x = F.shape[1]
    n_u = u.shape[1]
    n_y = C.shape[1]
    y = np.zeros((n_t, n_y))
    x = x0.copy()
    xn = np.zeros(n_x)
    for k in range(n_t):
        i = idx[k]
        a = w[k]
        b = 1.0 - a
        for o in range(n_y):
            acc = b * off[i, o] + a * off[i + 1, o]
            for j in range(n_x):
                acc += (b * C[i, o, j] + a * C[i + 1, o, j]) * x[j]
            for j in range(n_u):
                acc += (b * D[i, o, j] + a * D[i + 1, o, j]) * uo[k, j]
            y[k, o] = acc
        if k + 1 < n_t:
            i = idx_s[k]
            a = w_s[k]
            b = 1.0 - a
            for r in range(n_x):
                acc = 0.0
                for j in range(n_x):
                    acc += (b * F[i, r, j] + a * F[i + 1, r, j]) * x[j]
                for j in range(n_u):
                    acc += (b * G0[i, r, j] + a * G0[i + 1, r, j]) * u[k, j]
                    acc += (b * G1[i, r, j] + a * G1[i + 1, r, j]) * u[k + 1, j]
                xn[r] = acc
            for r in range(n_x):
                x[r] = xn[r]
    return y


_LOADED = False
# numba versions on which a cache lookup was checked to need nothing of the compiler's
# refresh but the runtime (tests/test_track_runs.py runs it in a fresh process)
_LEAN_LOAD_CHECKED = {(0, 68)}


def load_compiled() -> None:
    """Load the compiled recursion now (from numba's cache, or compile it): a process
    that forks workers afterwards hands it to them instead of each loading it again.

    Before it looks in its cache numba refreshes its whole compiler: it imports and
    installs every typing and lowering registry (0.2-0.25 s here; numba/numba#7516 on
    that cost), though machine code from the cache needs only numba's runtime. On the
    numba versions in _LEAN_LOAD_CHECKED that one refresh is cut to the runtime's start
    (the whole load then takes 0.05 s). A cache miss still compiles with numba's own
    refresh (the cut refresh removes itself when first called), and so does anything
    numba compiles later in the process."""
    global _LOADED
    if _LOADED:
        return
    z = np.zeros((2, 1, 1))
    i = np.zeros(1, np.int64)
    with _lean_cache_lookup():
        _ltv_run(z, z, z, z, z, np.zeros((2, 1)), i, np.zeros(1), i, np.zeros(1), np.zeros((1, 1)),
                 np.zeros((1, 1)), np.zeros(1))
    _LOADED = True


@contextlib.contextmanager
def _lean_cache_lookup():
    import numba

    ctx = getattr(_ltv_run, "targetctx", None)
    version = tuple(int(v) for v in numba.__version__.split(".")[:2] if v.isdigit())
    if ctx is None or version not in _LEAN_LOAD_CHECKED or "refresh" in vars(ctx):
        yield
        return
    from numba.core.runtime import rtsys

    def refresh_once():
        del ctx.refresh  # from now on numba's own, for anything it compiles
        rtsys.initialize(ctx)  # the runtime the cached code allocates its arrays with

    ctx.refresh = refresh_once
    try:
        yield
    finally:
        vars(ctx).pop("refresh", None)
