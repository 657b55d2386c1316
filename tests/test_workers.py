"""The worker processes beside a command (stid/workers.py): Ctrl-C ends the command with
its own one-line message, not a traceback from every worker, and does not wait for the
workers' jobs."""

from __future__ import annotations

import subprocess
import sys
import time

_SCRIPT = r"""
import os, signal, sys, time
from stid.workers import worker_pool

try:
    with worker_pool(2) as pool:
        assert pool is not None
        jobs = [pool.submit(time.sleep, 30) for _ in range(3)]  # one running per worker, one queued
        time.sleep(1.0)
        os.killpg(os.getpgrp(), signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
        time.sleep(30)
except KeyboardInterrupt:
    print("interrupted", file=sys.stderr)
    sys.exit(130)
"""


def test_ctrl_c_ends_the_command_and_its_workers_without_their_tracebacks():
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=60,
                         start_new_session=True)
    took = time.perf_counter() - t0
    assert out.returncode == 130, out.stderr
    assert out.stderr.strip() == "interrupted", out.stderr
    assert took < 15, took  # the 30 s jobs were stopped, not waited for


_HALF_WRITTEN = r"""
import time
from stid.workers import worker_pool

def result(n):
    return b"x" * n  # pickled and written to the result pipe piece by piece

for wait in (0.05, 0.1, 0.2):
    with worker_pool(2) as pool:
        jobs = [pool.submit(result, 10_000_000) for _ in range(4)]
        time.sleep(wait)  # the workers are writing their results when the pool ends
print("ended")
"""


def test_a_pool_ended_while_its_workers_write_results_does_not_hang():
    """A worker stopped in the middle of writing a result left half a message in the pipe, and
    the pool's exit waited for the rest for ever (a `stid diagnose` in the suite never returned;
    this script hung on its first pool before the fix)."""
    out = subprocess.run([sys.executable, "-c", _HALF_WRITTEN], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "ended", out.stderr
    assert "Traceback" not in out.stderr, out.stderr
