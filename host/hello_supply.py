"""A HELLO for a run in which none got through, taken from an earlier log of the same board.

The HELLO says how to turn counts into units (ADC scale, sensors, wheels). A board
sends the same configuration on every boot unless its firmware changed, so the
HELLO of an earlier log of the same board can stand in, marked with where it came
from. "The same board" is checked where the files allow it: the USB serial number
the logger recorded for the port (``stid.port`` metadata; on an RP2040 it is the
flash's unique id) must match; where neither file has one, the caller is warned that
it could not be checked.

A vehicle file cannot stand in (issue 12 asked whether it could). A HELLO declares what
only the board's firmware knows: the ADC's scale and reference (12-bit counts of 3.3 V on
an RP2040, millivolts on an ESP32), the tick modulus, which pin carries which sensor and
which hall which wheel, and the board's uid. A vehicle file describes the car (mass,
axles, steering, wheel radius); values typed there for the board would be a guess that no
check could catch, and a wrong guess converts every sample silently wrong. So
``--hello-from vehicle.toml`` is refused with one line, before anything is recorded.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from host.errors import HostError

MCAP_MAGIC = b"\x89MCAP"


def check_source(path) -> Path:
    """Refuse at once (before a run is recorded) a --hello-from that cannot supply a HELLO:
    a missing file, a vehicle file, anything that is not an MCAP log."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as e:
        raise HostError(f"--hello-from {path}: {e.strerror or e}; give an earlier log (.mcap) of the same board") \
            from None
    if head == MCAP_MAGIC:
        return path
    if _is_toml(path):
        raise HostError(f"--hello-from {path} is a vehicle file: it describes the car, not what only the board's "
                        "HELLO declares (ADC scale and reference, tick modulus, which pin is which sensor and "
                        "wheel, uid), and a guess at those would convert every sample wrong; give an earlier "
                        "log of the same board (--hello-from EARLIER.mcap)")
    raise HostError(f"--hello-from {path} is not an MCAP log; give an earlier log (.mcap) of the same board")


def _is_toml(path: Path) -> bool:
    try:
        if path.stat().st_size > 1 << 20:  # vehicle files are a few lines; a big file is data
            return False
        with open(path, "rb") as f:
            tomllib.load(f)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return True


def hello_from_file(path, port_info: dict | None) -> tuple[dict, str]:
    """(HELLO document marked ``supplied_from``, a warning to print) from an earlier log."""
    from host.mcap_read import read_log

    path = check_source(path)
    donor = read_log(path)
    if not donor.hello:
        raise HostError(f"{path} has no HELLO either; give a log of the same board that has one")
    doc = {k: v for k, v in donor.hello.items() if k != "supplied_from"}
    mine = (port_info or {}).get("usb_serial")
    theirs = (donor.metadata.get("stid.port") or {}).get("usb_serial")
    if mine and theirs and mine != theirs:
        raise HostError(f"{path} was logged from another board (USB serial {theirs}, this log's is {mine}); "
                        "give a log of the same board")
    doc["supplied_from"] = str(path)
    board = f"board uid {doc['uid']}" if doc.get("uid") else "a board without a uid"
    if mine and theirs:
        how = f"same USB serial number {mine}"
    else:
        how = "the files cannot tell whether it is the same board: check that it is"
    return doc, (f"no HELLO was received; its configuration is taken from {path} ({board}; {how}), "
                 "and marked so in the file")
