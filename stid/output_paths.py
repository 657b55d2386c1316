"""Where a command writes: nothing a user made is replaced unasked, and a path that cannot be
written is refused before any work (a light module: the CLI asks it before importing the
heavy ones)."""

from __future__ import annotations

from pathlib import Path

from stid.errors import InputError


def refuse_existing(paths, what: str, overwrite: bool) -> None:
    """Refuse to replace files that exist unless ``overwrite``; ``what``: the command's words
    for them and the option that names another path (e.g. "export ... --csv")."""
    # (a terminal, a pipe, /dev/stdout: written to, not replaced)
    there = [Path(p) for p in paths if Path(p).exists() and not (Path(p).is_char_device() or Path(p).is_fifo())]
    if there and not overwrite:
        names = ", ".join(map(str, there))
        raise InputError(f"{names} exist{'s' if len(there) == 1 else ''}: {what} does not replace a file "
                         "unasked; add --overwrite, or give another name")


def check_report_dir(out_dir, overwrite: bool = False) -> Path:
    """Refuse, without making anything, a report directory that is a file, that cannot be
    made, or that holds a report already (without ``overwrite``)."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"-o {out_dir} is a file: the report is a directory (report.html and its figures); "
                         "give a directory path")
    refuse_existing([out_dir / "report.html"], "stid report", overwrite)
    why = unwritable(out_dir)
    if why:
        raise InputError(f"cannot make the report directory {out_dir} ({why}): give one that can be written with -o")
    return out_dir


def unwritable(path) -> str:
    """Why nothing can be written at ``path`` (a directory that may not exist yet), or ''. Judged at
    its first part that exists, by making and removing a file there: access() says yes to root for
    /proc, where a trial user's `stid batch -o /proc/out.csv` failed after all the fitting."""
    import tempfile

    there = Path(path).absolute()
    while not there.exists() and there != there.parent:
        there = there.parent
    if not there.is_dir():
        return f"{there} is not a directory"
    try:
        with tempfile.NamedTemporaryFile(dir=there, prefix=".stid-"):
            pass
    except OSError as e:
        return f"cannot write in {there} ({e.strerror or e})"
    return ""
