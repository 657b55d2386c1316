"""The LPV simulation's loop has two builds (stid.models.recursion): C, compiled by `make`
and called through ctypes, and numba's where there is no C build. Both are held here to the
recursion written out densely in numpy, on systems of every size the models make."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from stid.models import recursion


def _system(rng, n_g, n_x, n_u, n_y, n_t):
    F = 0.3 * rng.normal(size=(n_g, n_x, n_x))
    G0, G1 = rng.normal(size=(n_g, n_x, n_u)), rng.normal(size=(n_g, n_x, n_u))
    C, D, off = rng.normal(size=(n_g, n_y, n_x)), rng.normal(size=(n_g, n_y, n_u)), rng.normal(size=(n_g, n_y))
    idx, idx_s = rng.integers(0, n_g - 1, n_t), rng.integers(0, n_g - 1, n_t)
    w, w_s = rng.random(n_t), rng.random(n_t)
    u, uo = rng.normal(size=(n_t, n_u)), rng.normal(size=(n_t, n_u))
    return F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, rng.normal(size=n_x)


def _dense(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0):
    """The recursion as its docstring states it, matrices interpolated per sample."""
    y = np.empty((len(u), C.shape[1]))
    x = x0.copy()
    for k in range(len(u)):
        i, a = idx[k], w[k]
        y[k] = ((1 - a) * C[i] + a * C[i + 1]) @ x + ((1 - a) * D[i] + a * D[i + 1]) @ uo[k] \
            + (1 - a) * off[i] + a * off[i + 1]
        if k + 1 < len(u):
            i, a = idx_s[k], w_s[k]

            def lerp(M):
                return (1 - a) * M[i] + a * M[i + 1]

            x = lerp(F) @ x + lerp(G0) @ u[k] + lerp(G1) @ u[k + 1]
    return y


def _builds():
    c = recursion.c_recursion()
    if c is None:
        if shutil.which(os.environ.get("CC", "cc")):
            pytest.fail(f"{recursion.LIBRARY.name} is not built (or older than its source): run `make bytecode`")
        pytest.skip("no C compiler: only numba's build of the recursion is there")
    return {"c": c, "numba": recursion.numba_recursion()}


# (grid nodes, states, inputs, outputs, samples): sizes the C build has as constants (1-9 states with
# the steer in and ay, r out; 5 with the tyre's force corrections in and the slip angles out) and others
@pytest.mark.parametrize("shape", [(2, 1, 1, 1, 1), (5, 2, 1, 2, 300), (3, 9, 1, 2, 50), (6, 5, 3, 4, 100),
                                   (12, 4, 3, 2, 500), (7, 6, 3, 3, 200), (4, 12, 1, 2, 60)])
def test_both_builds_of_the_recursion_are_the_recursion_written_out(shape):
    rng = np.random.default_rng(sum(shape))
    args = _system(rng, *shape)
    want = _dense(*args)
    for name, run in _builds().items():
        got = run(*args)
        assert got.shape == want.shape
        assert np.max(np.abs(got - want)) <= 1e-12 * max(1.0, np.max(np.abs(want))), name


def test_the_c_build_takes_arrays_of_any_layout_and_refuses_an_index_outside_the_grid():
    run = _builds()["c"]
    rng = np.random.default_rng(3)
    F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0 = _system(rng, 6, 3, 2, 2, 80)
    want = _dense(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0)
    # Fortran-ordered matrices, a strided input, indices of another integer type: copied as the loop reads them
    got = run(np.asfortranarray(F), G0, G1, C, D, off, idx.astype(np.int32), w, idx_s, w_s,
              np.repeat(u, 2, axis=0)[::2], uo, x0)
    assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))
    bad = idx.copy()
    bad[40] = 5  # the last node has no upper neighbour
    with pytest.raises(ValueError, match="outside the grid"):
        run(F, G0, G1, C, D, off, bad, w, idx_s, w_s, u, uo, x0)
    with pytest.raises(ValueError, match="shape"):
        run(F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0[:2])


def test_a_command_starts_without_numba_where_the_c_build_is_there(tmp_path):
    """numba's import and its cache's load were 0.18 s of every cold command: a fit on a track
    run (its speed varies, so the LPV recursion runs) now never imports numba."""
    _builds()
    script = r"""
import sys
import numpy as np
from stid.fit.fitting import fit
from stid.models import recursion
from stid.run import Run
from stid.vehicle_file import Vehicle
rng = np.random.default_rng(0)
n = 4000
t = np.arange(n) / 100.0
steer = np.convolve(rng.standard_normal(n), np.ones(25) / 25, "same") * 0.1
vx = 4.0 + 0.5 * np.sin(t / 3)
ay = 6.0 * np.convolve(steer, np.ones(8) / 8, "same") * vx + 0.05 * rng.standard_normal(n)
r = ay / vx
res = fit([Run("r", t, steer, ay, r, vx, None, None, {}, {})], Vehicle("v", 9.3, 0.23, 0.29), "bicycle", "time")
print(recursion.used, "numba" in sys.modules, res.converged)
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    used, numba_loaded, _ = out.stdout.split()
    assert used == "c" and numba_loaded == "False", out.stdout


def test_a_c_build_older_than_its_source_is_not_used(tmp_path, monkeypatch):
    _builds()
    stale = tmp_path / "_ltv_recursion.so"
    shutil.copy(recursion.LIBRARY, stale)
    source = tmp_path / "ltv_recursion.c"
    source.write_text(recursion.SOURCE.read_text())
    os.utime(stale, ns=(1, 1))  # built before the source was last changed
    monkeypatch.setattr(recursion, "LIBRARY", stale)
    monkeypatch.setattr(recursion, "SOURCE", source)
    assert recursion.c_recursion() is None
    os.utime(stale, None)
    assert recursion.c_recursion() is not None
