"""The installed distribution's version, for the ``--version`` of the commands that do not
import stid (host/ and hil_sim/ stand on their own)."""

from __future__ import annotations


def installed_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("stid")
    except PackageNotFoundError:
        return "unknown (not installed)"
