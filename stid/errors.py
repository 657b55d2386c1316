"""The errors a user can cause. The CLI prints their message and exits non-zero."""


class StidError(Exception):
    """Root of every user-facing error; the message says what is wrong and what to do."""

    exit_code = 2


class InputError(StidError, ValueError):
    """A file or an argument is not what stid needs."""


class ToolMissing(StidError, RuntimeError):
    """An external tool (mpy-cross, mpremote, micropython) is not installed."""
