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
