"""Progress on the terminal for work that takes more than a second; silent when
stderr is not a terminal (pipes, CI, --json consumers)."""

from __future__ import annotations

import sys
import threading
import time


class Progress:
    """``with Progress("diagnosing") as p: ... p.step("tyre_relaxation")``."""

    def __init__(self, what: str, stream=None, delay: float = 1.0):
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty()
        self.what = what
        self.detail = ""
        self.delay = delay
        self._stop = threading.Event()
        self._thread = None
        self._shown = False

    def step(self, detail: str) -> None:
        self.detail = detail

    def _run(self):
        t0 = time.monotonic()
        if self._stop.wait(self.delay):
            return
        frames = "|/-\\"
        k = 0
        while not self._stop.wait(0.2):
            line = f"\r{frames[k % 4]} {self.what} {self.detail}  {time.monotonic() - t0:4.1f} s"
            self.stream.write(line[:120].ljust(80))
            self.stream.flush()
            self._shown = True
            k += 1

    def __enter__(self):
        if self.enabled:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        if self._thread:
            self._stop.set()
            self._thread.join()
            if self._shown:
                self.stream.write("\r" + " " * 80 + "\r")
                self.stream.flush()
        return False
