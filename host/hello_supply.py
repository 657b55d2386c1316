"""A HELLO for a run in which none got through, taken from an earlier log of the same board.

The HELLO says how to turn counts into units (ADC scale, sensors, wheels). A board
sends the same configuration on every boot unless its firmware changed, so the
HELLO of an earlier log of the same board can stand in, marked with where it came
from. "The same board" is checked where the files allow it: the USB serial number
the logger recorded for the port (``stid.port`` metadata; on an RP2040 it is the
flash's unique id) must match; where neither file has one, the caller is warned that
it could not be checked.
"""

from __future__ import annotations

from pathlib import Path

from host.errors import HostError


def hello_from_file(path, port_info: dict | None) -> tuple[dict, str]:
    """(HELLO document marked ``supplied_from``, a warning to print) from an earlier log."""
    from host.mcap_read import read_log

    path = Path(path)
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
