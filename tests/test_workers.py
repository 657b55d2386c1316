"""The worker processes beside a command (stid/workers.py): Ctrl-C ends the command with
its own one-line message, not a traceback from every worker, and does not wait for the
workers' jobs."""

from __future__ import annotations

import json
import subprocess
import sys
import time

# (each script first takes Ctrl-C as a terminal's foreground command does: a suite started as a
# shell's background job hands its children SIGINT ignored, and Python then leaves it so)
_SCRIPT = r"""
import os, signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)
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


_BLAS_THREADS = r"""
import json, os
import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits
from stid.workers import worker_pool

def blas_threads():
    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

threadpool_limits(limits=2, user_api="blas")  # as a 2-core machine starts: more than one
np.linalg.svd(np.random.default_rng(0).normal(size=(40000, 5)), full_matrices=False)  # BLAS awake
before = blas_threads()
with worker_pool(2) as pool:
    inside = blas_threads()
    in_worker = pool.submit(blas_threads).result()
after = blas_threads()
print(json.dumps({"before": before, "inside": inside, "worker": in_worker, "after": after}))
"""


def test_blas_runs_one_thread_per_process_while_workers_run_and_is_given_back_after():
    """BLAS's threads wait for work spinning: with worker processes beside them they took the
    cores from the workers (a diagnosis called from Python ran 2-3x slower than as a command).
    While a pool runs, this process and its workers use one BLAS thread each; afterwards this
    process has its own setting back."""
    out = subprocess.run([sys.executable, "-c", _BLAS_THREADS], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got == {"before": [2], "inside": [1], "worker": [1], "after": [2]}, got


_KILLED = r"""
import os, sys, time
from stid.workers import worker_pool

with worker_pool(2) as pool:
    jobs = [pool.submit(time.sleep, 60) for _ in range(2)]
    time.sleep(1.0)
    print(" ".join(str(p) for p in pool._processes), flush=True)
    time.sleep(60)
"""


def test_a_command_killed_outright_takes_its_workers_with_it():
    """SIGKILL cannot be caught: the command's finally never runs. Its workers, waiting on a
    pipe every one of them also holds open, lingered for ever (a served `stid report` whose
    server was killed left two)."""
    import os
    import signal

    p = subprocess.Popen([sys.executable, "-c", _KILLED], stdout=subprocess.PIPE, text=True)
    workers = [int(w) for w in p.stdout.readline().split()]
    assert len(workers) == 2
    p.kill()
    p.wait(timeout=10)
    deadline = time.monotonic() + 10
    alive = workers
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = []
        for w in workers:
            try:
                os.kill(w, 0)
                with open(f"/proc/{w}/stat") as f:
                    if f.read().rsplit(")", 1)[1].split()[0] != "Z":
                        alive.append(w)
            except (ProcessLookupError, FileNotFoundError):
                pass
    for w in alive:
        os.kill(w, signal.SIGKILL)
    assert not alive, f"workers left running after their command was killed: {alive}"


_CANCELLED_WHILE_WAITING = r"""
import time
from stid.workers import worker_pool

def slow(b):
    time.sleep(30)
    return len(b)

with worker_pool(2) as pool:
    jobs = [pool.submit(slow, b"x" * 20_000_000) for _ in range(5)]
    time.sleep(1.0)  # two run, one is half written into the job pipe (no worker reads it), two wait
    assert jobs[4].cancel()  # a job started ahead and not needed
print("ended")
"""


def test_a_pool_ended_with_a_cancelled_job_waiting_ends_without_a_traceback():
    """On Python 3.11 the executor's thread raised InvalidStateError for the cancelled job when the
    pool was ended, printed its traceback, and left the half-written job's feeder blocked: the
    interpreter's exit then waited for ever (a `stid diagnose --peel` interrupted 1.5 s in hung so)."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _CANCELLED_WHILE_WAITING], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "ended", out.stderr
    assert "Traceback" not in out.stderr and "Exception in thread" not in out.stderr, out.stderr
    assert time.perf_counter() - t0 < 20  # the 30 s jobs were not waited for


_LOST_IN_A_FORK = r"""
import os, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)
lost = []

def lose():  # a Ctrl-C that lands in an after-fork handler (logging's, in the suite), once
    if not lost:
        lost.append(1)
        raise KeyboardInterrupt

os.register_at_fork(after_in_parent=lose)
from stid.cli import main_here
sys.exit(main_here(sys.argv[1:]))
"""


def test_a_ctrl_c_that_lands_in_a_fork_handler_still_ends_the_command():
    """Python drops an exception raised in an after-fork handler ("Exception ignored in"): a
    served `stid diagnose --peel` interrupted while its pool forked ran on to its end and exited
    0 (CI, stop 32). The command (the real log's diagnosis, whose pool forks) now ends with 130."""
    from conftest import REPO

    real = REPO / "tests" / "fixtures" / "real" / "frictionmaps"
    out = subprocess.run([sys.executable, "-c", _LOST_IN_A_FORK, "diagnose", "ds3.csv", "--vehicle", "vehicle.toml"],
                         capture_output=True, text=True, timeout=120, cwd=real)
    assert out.returncode == 130, out.stderr[-2000:]
    assert out.stderr.strip().endswith("interrupted") and "Exception ignored" not in out.stderr, out.stderr[-2000:]
    assert out.stdout == "", "the diagnosis ran on to print its result"


_SHARED = r"""
import json, os, time
from stid.search.pool import shared
from stid.workers import worker_pool

def job(seconds):
    time.sleep(seconds)
    return os.getpid()

with worker_pool(2) as pool:
    pids = shared(pool, job, [0.8, 0.6, 0.05, 0.05, 0.05])
    # a pool whose workers are gone: what was not handed over is done here
    pool.shutdown(wait=True)
    late = shared(pool, job, [0.01, 0.01, 0.01])
print(json.dumps({"here": os.getpid(), "pids": pids, "late": late}))
"""


def test_jobs_shared_with_the_workers_are_not_left_waiting_in_their_queue_while_this_process_idles():
    """stid.search.pool.shared: the two long jobs go to the two workers, and this process does
    the three short ones itself, one after the other. Before, every job was handed to the pool at
    once and a third waited in its queue (where it counts as started and cannot be taken back)
    while this process, done with its own, waited for a worker (a diagnosis's four candidates)."""
    out = subprocess.run([sys.executable, "-c", _SHARED], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    here, pids = got["here"], got["pids"]
    assert pids[2:] == [here] * 3, got  # the short ones, here
    assert len({pids[0], pids[1], here}) == 3, got  # each long one in a worker of its own
    assert got["late"] == [here] * 3, got
