"""The compiled loop that simulates a linear parameter-varying model (stid.models.lpv):

    y[k]   = C(k) x + D(k) uo[k] + off(k)
    x[k+1] = F(k) x + G0(k) u[k] + G1(k) u[k+1]

every matrix interpolated between two speed-grid nodes per sample. Two builds of the same loop:
C (ltv_recursion.c, compiled by `make` into _ltv_recursion.so beside it, called through ctypes),
and numba's (stid.models._ltv_numba) where there is no such build (no C compiler, an install
without make, a source newer than its build). They agree to round-off (tests/test_recursion.py).
The C build is for start-up: numba's import and its cache's load cost every cold command 0.18 s
(the recursion's own speed is the same: 0.58 ms on 14,000 samples for either)."""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("ltv_recursion.c")
LIBRARY = Path(__file__).with_name("_ltv_recursion.so")
ABI = 1  # ltv_recursion_abi() of a build whose arguments are the ones _c_recursion passes

_run = None
# which build ltv_run calls ("c" or "numba"), once loaded
used = None


def load() -> str:
    """Load the compiled recursion now (a process that forks workers afterwards hands it to them);
    returns which build it is."""
    global _run, used
    if _run is None:
        c = c_recursion()
        _run, used = (c, "c") if c is not None else (numba_recursion(), "numba")
    return used


def ltv_run(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0) -> np.ndarray:
    """The outputs (n_t, n_y) of the recursion: F (n_g, n_x, n_x), G0, G1 (n_g, n_x, n_u), C
    (n_g, n_y, n_x), D (n_g, n_y, n_u), off (n_g, n_y) at the grid's nodes; per sample the lower
    node and the weight of the upper one for the outputs (idx, w) and the step (idx_s, w_s); the
    held inputs u and the inputs the outputs take straight through uo (n_t, n_u); x0 (n_x)."""
    if _run is None:
        load()
    return _run(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0)


def c_recursion():
    """The C build's recursion, or None where there is none to use: not built, older than its
    source, or of other arguments (ABI)."""
    try:
        if LIBRARY.stat().st_mtime_ns < SOURCE.stat().st_mtime_ns:
            return None  # (the source changed since: numba runs the loop until `make` builds it again)
        lib = ctypes.CDLL(str(LIBRARY))
        if lib.ltv_recursion_abi() != ABI:
            return None
    except (OSError, AttributeError):
        return None
    fn = lib.ltv_run
    fn.restype = ctypes.c_int64
    fn.argtypes = [ctypes.c_void_p] * 14 + [ctypes.c_int64] * 5
    f64, i64 = np.float64, np.int64

    def run(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0):
        # the loop reads raw memory: every array C-ordered in the type it reads (no copy where it is)
        F, G0, G1, C, D, off, w, w_s, u, uo, x0 = (np.ascontiguousarray(a, f64)
                                                   for a in (F, G0, G1, C, D, off, w, w_s, u, uo, x0))
        idx, idx_s = np.ascontiguousarray(idx, i64), np.ascontiguousarray(idx_s, i64)
        n_t, n_u = u.shape
        n_g, n_x, n_y = F.shape[0], F.shape[1], C.shape[1]
        if not (G0.shape == G1.shape == (n_g, n_x, n_u) and C.shape == (n_g, n_y, n_x) and D.shape == (n_g, n_y, n_u)
                and off.shape == (n_g, n_y) and uo.shape == u.shape and x0.shape == (n_x,)
                and len(idx) >= n_t and len(w) >= n_t and len(idx_s) >= n_t - 1 and len(w_s) >= n_t - 1):
            raise ValueError("the recursion's arrays do not agree in shape")
        y = np.empty((n_t, n_y))
        status = fn(F.ctypes.data, G0.ctypes.data, G1.ctypes.data, C.ctypes.data, D.ctypes.data, off.ctypes.data,
                    idx.ctypes.data, w.ctypes.data, idx_s.ctypes.data, w_s.ctypes.data, u.ctypes.data,
                    uo.ctypes.data, x0.ctypes.data, y.ctypes.data, n_t, n_g, n_x, n_u, n_y)
        if status == -1:
            raise ValueError("a grid index outside the grid")  # (checked in the loop: a read beyond it crashes)
        if status != 0:
            raise MemoryError("the recursion could not allocate its state")
        return y

    return run


def numba_recursion():
    """numba's build of the loop, loaded (compiled the first time, from numba's cache after)."""
    from stid.models import _ltv_numba

    _ltv_numba.load_compiled()
    return _ltv_numba._ltv_run
