"""The errors a user can cause. The CLI prints their message and exits non-zero."""


class StidError(Exception):
    """Root of every user-facing error; the message says what is wrong and what to do."""

    exit_code = 2


class InputError(StidError, ValueError):
    """A file or an argument is not what stid needs."""


class ToolMissing(StidError, RuntimeError):
    """An external tool (mpy-cross, mpremote, micropython) is not installed."""


def unknown_key(where, what, key, known, inside="") -> InputError:
    """An unknown key of a user's file, named with the nearest known one (vehicle file, its
    [csv] and [ros] tables)."""
    import difflib

    near = difflib.get_close_matches(key, known, n=1)
    todo = f"did you mean '{near[0]}'?" if near else "rename or remove it"
    inside = f" in {inside}" if inside else ""
    return InputError(f"{where}: unknown {what} '{key}'{inside}: {todo} (known {what}s: {', '.join(known)})")
