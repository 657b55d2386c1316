"""The worker processes one diagnose shares its independent fits between, and the ways
fits are handed to them (stid.workers holds the pool itself)."""

from __future__ import annotations

import collections
import threading
from concurrent.futures import Future

from stid import workers
from stid.models.effect import available_effects
from stid.models.model import parse_model_name

WORKERS = workers.WORKERS


def worker_pool():
    """Worker processes for one diagnose (None on a one-core machine): the candidates'
    fits, the evidence's per-speed refits and the noise floor are independent, and run
    beside each other. Forked after the compiled simulator and the effect catalogue are
    loaded, so the workers share them instead of each loading them (the catalogue's modules
    cost each worker 10-20 ms at its first job)."""
    from stid.models import recursion

    def before_fork():
        recursion.load()
        available_effects()

    return workers.worker_pool(WORKERS, before_fork=before_fork)


def in_workers(model_name: str) -> bool:
    """Effects defined in the user's own modules (a test file, a notebook) may not be
    importable in a worker process: models with one run in this process."""
    _, effects = parse_model_name(model_name)
    return all(available_effects()[e].__module__.startswith("stid.effects.") for e in effects)


def mapper(pool, model_name: str):
    """A map over independent fits of ``model_name``: all but the last in the worker pool, the
    last here, where this process would otherwise only wait. With a worker still busy on a fit
    started ahead of need, two fits then run side by side, not one after the other on the
    free worker (a job the pool has queued counts as started: it cannot be taken back)."""
    if pool is None or not in_workers(model_name):
        return map
    return lambda fn, jobs: shared(pool, fn, list(jobs))


def shared(pool, fn, jobs: list, order=None) -> list:
    """``[fn(job) for job in jobs]``, the jobs shared between the worker pool and this process:
    the workers take them from the front of ``order`` (the costliest first, when ordered so),
    this process from the back, until none is left. The pool is handed one job per worker at a
    time, each worker's next when it finishes one: a job handed over early waits in the pool's
    queue, where it counts as started and cannot be taken back, while this process, done with
    its own, waits for it (a diagnosis's four candidates: 0.1-0.2 s idle of 0.55 s)."""
    order = list(range(len(jobs)) if order is None else order)
    if pool is None or len(jobs) < 2:
        return [fn(jobs[i]) for i in range(len(jobs))]
    left = collections.deque(order)
    futures: dict = {}
    lock = threading.Lock()

    def hand_one(_done=None):
        with lock:
            if not left:
                return
            i = left.popleft()
            try:
                futures[i] = pool.submit(fn, jobs[i])
            except RuntimeError:  # the pool is shut down or broken: what is left is done here
                left.appendleft(i)
                return
        futures[i].add_done_callback(hand_one)  # (runs at once if it is done already)

    for _ in range(min(WORKERS, len(jobs) - 1)):
        hand_one()
    here = {}
    while True:
        with lock:
            if not left:
                break
            i = left.pop()
        here[i] = fn(jobs[i])
    return [here[i] if i in here else futures[i].result() for i in range(len(jobs))]


def shares(items: list, n: int, cost) -> list:
    """``items`` in at most ``n`` shares of about equal ``cost``, each in the items' order
    (the largest first to the share that has least)."""
    out = [[] for _ in range(min(n, len(items)))]
    load = [0.0] * len(out)
    for i in sorted(range(len(items)), key=lambda i: -cost(items[i])):
        k = load.index(min(load))
        out[k].append(i)
        load[k] += cost(items[i])
    return [[items[i] for i in sorted(share)] for share in out]


class Ahead:
    """Jobs ``fn(job)`` started in the worker pool ahead of need (in ``order``), and read when
    needed. A job no worker has started when it is needed is done here instead of waited for.
    ``window``: at most that many jobs, from the one being read on, are started (for jobs read in
    order that may not all be needed: a worker busy with one that is not holds up what follows)."""

    def __init__(self, pool, fn, jobs, order=None, window=None, known=None):
        self.pool, self.fn, self.jobs = pool, fn, jobs
        self.order = list(range(len(jobs)) if order is None else order)
        self.window = len(jobs) if window is None else window
        self.futures = [None] * len(jobs)
        for i, result in (known or {}).items():  # done already, elsewhere
            self.futures[i] = Future()
            self.futures[i].set_result(result)
        self._submit_up_to(self.window)

    def _submit_up_to(self, n):
        if self.pool is not None:
            for i in self.order[:n]:
                if self.futures[i] is None:
                    self.futures[i] = self.pool.submit(self.fn, self.jobs[i])

    def result(self, i):
        self._submit_up_to(self.order.index(i) + self.window)
        f = self.futures[i]
        if f is None or f.cancel():
            return self.fn(self.jobs[i])
        return f.result()

    def drop_the_rest(self):
        """Those not needed: cancelled if not started (a running one is ended with the pool)."""
        for f in self.futures:
            if f is not None:
                f.cancel()
