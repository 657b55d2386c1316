"""Worker processes beside a command's own: the independent pieces of its work (the noise
floor beside a fit, the candidates of a diagnosis) run on the machine's other cores."""

from __future__ import annotations

import contextlib
import os

WORKERS = min(2, os.cpu_count() or 1)


@contextlib.contextmanager
def worker_pool(workers: int = WORKERS, before_fork=None):
    """A process pool of ``workers`` (None on a one-core machine, and inside a daemonic
    process: a worker of another pool, e.g. a Dask worker running `stid batch --diagnose`,
    may not start processes of its own, so it does everything itself). ``before_fork()``
    runs first, so that what it loads is shared with the workers instead of loaded by each."""
    import multiprocessing

    if workers < 1 or WORKERS < 2 or multiprocessing.current_process().daemon:
        yield None
        return
    from concurrent.futures import ProcessPoolExecutor

    if before_fork is not None:
        before_fork()
    with ProcessPoolExecutor(max_workers=workers) as ex:
        yield ex
