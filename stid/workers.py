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

    from threadpoolctl import threadpool_limits

    if before_fork is not None:
        before_fork()
    # One BLAS thread in this process and in the workers (forked with this limit): the cores are
    # the processes', and BLAS's own threads, which wait spinning for their next job, took them
    # from the other processes. A diagnosis called from Python (a notebook, the bench) ran 2-3x
    # slower than alone (a command gained 5-10%); stid's matrices are a few columns wide, where
    # BLAS threads add nothing (a fit of 330,000 samples: the same wall time, half the CPU).
    limit = threadpool_limits(limits=1, user_api="blas")
    ex = ProcessPoolExecutor(max_workers=workers, initializer=_start_worker, initargs=(os.getpid(),))
    try:
        yield ex
    finally:
        # the command has what it needs (or was interrupted, or failed): whatever a worker is
        # still doing is of no use (a fit started ahead of need), and is not waited for.
        # Terminated before the shutdown: the other order hangs at interpreter exit
        _forget_cancelled_jobs_when_broken(ex)
        procs = list((getattr(ex, "_processes", None) or {}).values())  # (no public way to stop them)
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join()
        # A worker stopped while it wrote a result leaves half a message in the result pipe, and
        # the executor's thread waits for the rest for ever (shutdown then hangs: a diagnosis
        # that never returned, seen once in the suite). This process holds the pipe's last
        # writing end: closed, the half message ends in EOF and the executor sees a broken pool.
        writer = getattr(getattr(ex, "_result_queue", None), "_writer", None)
        if writer is not None:
            writer.close()
        try:
            ex.shutdown(wait=True, cancel_futures=True)
        finally:
            limit.restore_original_limits()


def _forget_cancelled_jobs_when_broken(ex) -> None:
    """The pool is ended by terminating its workers, which the executor's thread sees as a broken
    pool: it then marks every job still waiting as failed. On Python 3.11 a job cancelled while it
    waited (a fit started ahead and not needed) makes that raise InvalidStateError: the thread died
    with a traceback on the user's terminal before it closed the job pipe, and a job half written
    into that pipe then held the interpreter's exit for ever (reproduced: tests/test_workers.py;
    a `stid diagnose --peel` interrupted 1.5 s in hung so). Newer CPython ignores the error there
    (concurrent/futures/process.py, terminate_broken); here the cancelled ones are left out first,
    in the executor's own thread (where the shutdown's cancels happen too)."""
    thread = getattr(ex, "_executor_manager_thread", None)
    if thread is None or not hasattr(thread, "terminate_broken"):
        return
    original = thread.terminate_broken

    def terminate_broken(cause):
        for work_id, item in list(thread.pending_work_items.items()):
            if item.future.cancelled():
                del thread.pending_work_items[work_id]
        original(cause)

    thread.terminate_broken = terminate_broken


def _start_worker(command_pid: int) -> None:
    _leave_interrupts_to_the_command()
    _end_with_the_command(command_pid)


def _end_with_the_command(command_pid: int) -> None:
    """A command killed outright (SIGKILL, the OOM killer) cannot end its workers, and they
    would wait for work for ever: each holds the job pipe's writing end too, so none reads an
    end of file (seen: a served `stid report` whose server was killed left two). On Linux the
    kernel ends a worker with its command (PR_SET_PDEATHSIG); elsewhere this does nothing."""
    import signal

    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, int(signal.SIGTERM), 0, 0, 0) != 0:  # PR_SET_PDEATHSIG = 1
            return
    except (OSError, AttributeError):  # not Linux
        return
    if os.getppid() != command_pid:  # the command was gone before the kernel was asked
        os._exit(1)


def _leave_interrupts_to_the_command():
    """Ctrl-C reaches every process of the group: a worker ignores it (else each prints its
    own traceback) and the command, which gets it too, ends the workers and says so."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
