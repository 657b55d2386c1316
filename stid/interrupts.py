"""A Ctrl-C is never lost: Python drops an exception raised where nothing can receive it, and
a KeyboardInterrupt is one like any other there.

Seen in the suite (a served `stid diagnose --peel`, Ctrl-C 0.5 s in): the interrupt landed while
the worker pool forked, in logging's after-fork handler, where CPython prints "Exception ignored
in: <function _releaseLock>" and goes on. The command then ran to its end and exited 0, as if the
user had not pressed anything. The same holds wherever Python calls code it cannot raise out of
(after-fork handlers, ``__del__``, weakref callbacks), in a cold command as in a served one.

Here such an interrupt is delivered again, to the main thread, once the call that lost it has
returned. It cannot be raised from the hook itself: the hook is one more place that cannot raise
(CPython 3.11 runs a pending signal's handler right after a call returns, inside the hook). So a
thread raises it a moment later, and if that lands in a handler too, it is delivered again."""

from __future__ import annotations

import contextlib
import sys

REDELIVER_AFTER_S = 0.05  # long enough for the hook to have returned, short beside a user's patience


@contextlib.contextmanager
def interrupts_kept():
    """Within this, a KeyboardInterrupt that Python would drop reaches the main thread again."""
    import signal
    import threading

    main = threading.main_thread().ident
    before = sys.unraisablehook

    def hook(unraisable):
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
            # a signal, not _thread.interrupt_main: only a signal wakes a main thread that waits
            # on a lock (a future's result) to run its handler
            again = threading.Timer(REDELIVER_AFTER_S, signal.pthread_kill, (main, signal.SIGINT))
            again.daemon = True  # (an interrupt that comes after the command's end has no one to stop)
            again.start()
            return
        before(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = before
