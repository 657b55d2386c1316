"""``stid-log --live``: the live view (``stid live FILE --follow``) as a process of its own.

The logger only starts it and hands it its lines; it never waits for it while logging.
The view reads the file the logger flushes every second, so estimation costs the logger
no sample: it runs in another process, at a lower priority (``NICE``), and when the
machine is short of CPU it is the view that slows down. The host imports nothing of
``stid``: the view is a command line, like any other program reading the file.

On a terminal the view owns it (its table is redrawn in place), so the logger's own
lines go through the view, which prints them above the table. Ctrl-C stops the logger,
not the view (it is in a session of its own): the logger finishes the file, closes the
view's input, and the view makes one last update on the finished file.
"""

from __future__ import annotations

import argparse
import errno
import os
import subprocess
import sys

NICE = 10  # below the logger; the view's background diagnosis goes lower still
FINAL_UPDATE_S = 60.0  # at the end: at most this long for the last update on the finished file


class LiveView:
    def __init__(self, path, argv: list[str]):
        cmd = [sys.executable, "-m", "stid.cli", "live", str(path), "--follow", "--from-logger", *argv]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, preexec_fn=lambda: os.nice(NICE),
                                     start_new_session=True)
        os.set_blocking(self.proc.stdin.fileno(), False)  # a view that stops reading never blocks the logger

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def say(self, text: str) -> bool:
        """Hand a line to the view to show; False when it could not take it (then say it yourself)."""
        if not self.alive or self.proc.stdin.closed:
            return False
        try:
            os.write(self.proc.stdin.fileno(), (text.replace("\n", " ") + "\n").encode())
            return True
        except (BlockingIOError, BrokenPipeError, OSError):
            return False

    def finish(self) -> int | None:
        """The file is finished: let the view make its last update and end; its exit code."""
        try:
            self.proc.stdin.close()
        except OSError as e:
            if e.errno != errno.EPIPE:
                raise
        try:
            return self.proc.wait(timeout=FINAL_UPDATE_S)
        except subprocess.TimeoutExpired:
            self.proc.terminate()
            try:
                return self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                return self.proc.wait()


def web_port(text: str) -> int:
    """``--web PORT`` (of ``stid live`` and ``stid-log --live``): a TCP port, 1-65535, or 0 for a free
    one (a port beyond them ended in Python's OverflowError)."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port: give 1-65535, or --web alone for a free one")
    return port
