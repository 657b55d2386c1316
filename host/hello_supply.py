"""A HELLO for a run in which none got through, taken from an earlier log of the same board.

The HELLO says how to turn counts into units (ADC scale, sensors, wheels). A board
sends the same configuration on every boot unless its firmware changed, so the
HELLO of an earlier log of the same board can stand in, marked with where it came
from. "The same board" is checked where the files allow it: the USB serial number
the logger recorded for the port (``stid.port`` metadata; on an RP2040 it is the
flash's unique id) must match; where neither file has one, the caller is warned that
it could not be checked.

A vehicle file can stand in only where it declares the board: a ``[board]`` table that
holds the HELLO's own keys (docs/hello_in_vehicle_file.md). A HELLO declares what only the
board's firmware knows: the ADC's scale and reference (12-bit counts of 3.3 V on an
RP2040, microvolts on an ESP32), the tick modulus, which channel is which sensor (ratiometric
or absolute output, its bandwidth) and which hall which wheel. The rest of a vehicle file
describes the car, and nothing in it could stand for those, so a vehicle file without a
complete ``[board]`` is refused with one line (naming what is missing) before anything is
recorded. A declared ``[board]`` is used with a warning: no check can catch a wrong value
there, and a wrong value converts every sample wrong.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from host.errors import HostError

MCAP_MAGIC = b"\x89MCAP"


def check_source(path) -> Path:
    """Refuse at once (before a run is recorded) a --hello-from that cannot supply a HELLO:
    a missing file, a vehicle file without a complete [board] table, anything else that is
    not an MCAP log."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as e:
        raise HostError(f"--hello-from {path}: {e.strerror or e}; give an earlier log (.mcap) of the same board") \
            from None
    if head == MCAP_MAGIC:
        return path
    doc = _toml(path)
    if doc is not None:
        _board_of(path, doc)  # refuses, naming what is missing
        return path
    raise HostError(f"--hello-from {path} is not an MCAP log (nor a vehicle file); give an earlier log (.mcap) "
                    "of the same board, or a vehicle file with a [board] table (docs/hello_in_vehicle_file.md)")


# What a HELLO must declare for its samples to be converted (host/units.py, stid/load.py)
BOARD_KEYS = {"proto": "the protocol version", "rate_hz": "the sample rate [Hz]",
              "mod": "the tick modulus (1073741824 for MicroPython's ticks_us)",
              "adc": "the ADC: {bits, vref, unit}"}
ADC_KEYS = ("bits", "vref", "unit")


def _board_of(path: Path, doc: dict) -> dict:
    board = doc.get("board")
    if not isinstance(board, dict):
        raise HostError(f"--hello-from {path} is a vehicle file without a [board] table: it describes the car, "
                        "not what only the board's HELLO declares (ADC scale and reference, tick modulus, which "
                        "channel is which sensor and wheel); declare the board there (docs/hello_in_vehicle_file.md) "
                        "or give an earlier log of the same board (--hello-from EARLIER.mcap)")
    missing = [f"{k} ({what})" for k, what in BOARD_KEYS.items() if k not in board]
    adc = board.get("adc")
    if isinstance(adc, dict):
        missing += [f"adc.{k}" for k in ADC_KEYS if k not in adc]
    channels = board.get("channels")  # optional (protocol 2 had none): the sensors' bandwidths
    if channels is not None:
        missing += [f"channels.{k}" for k in ("ax", "ay", "yaw")
                    if not isinstance(channels, dict) or not isinstance(channels.get(k), dict)]
    if missing:
        raise HostError(f"--hello-from {path}: its [board] table lacks {'; '.join(missing)} "
                        "(docs/hello_in_vehicle_file.md); or give an earlier log of the same board")
    wrong = _wrong_values(board)
    if wrong:
        raise HostError(f"--hello-from {path}: in its [board] table {'; '.join(wrong)} "
                        "(docs/hello_in_vehicle_file.md)")
    return board


def _wrong_values(board: dict) -> list:
    """What a declared HELLO holds that no board sends (a typo converts every sample wrong)."""
    from host import protocol

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    out = []
    proto = board["proto"]
    if not isinstance(proto, int) or isinstance(proto, bool) or not 1 <= proto <= protocol.VERSION:
        out.append(f"proto = {proto!r} is not a protocol this stid reads (1 to {protocol.VERSION})")
    if not number(board["rate_hz"]) or board["rate_hz"] <= 0:
        out.append(f"rate_hz = {board['rate_hz']!r} must be a positive number [Hz]")
    if not isinstance(board["mod"], int) or isinstance(board["mod"], bool) or board["mod"] < 2:
        out.append(f"mod = {board['mod']!r} must be the tick modulus, an integer (1073741824)")
    adc = board["adc"]
    if not isinstance(adc.get("bits"), int) or not 8 <= adc["bits"] <= 16:
        out.append(f"adc.bits = {adc.get('bits')!r} must be the ADC's bits (12)")
    if not number(adc.get("vref")) or not 0.5 <= adc["vref"] <= 5.5:
        out.append(f"adc.vref = {adc.get('vref')!r} must be the reference in volts (3.3)")
    if adc.get("unit") not in ("count", "mV"):
        out.append(f"adc.unit = {adc.get('unit')!r} must be \"count\" (RP2040) or \"mV\" (ESP32)")
    wheels = board.get("wheels", [])
    if not isinstance(wheels, list) or not all(isinstance(w, dict) and isinstance(w.get("pulses_per_rev"), int)
                                               and w["pulses_per_rev"] > 0 for w in wheels):
        out.append("wheels must be a list of {pulses_per_rev = N, wheel = \"rl\"} tables")
    return out


def _toml(path: Path) -> dict | None:
    try:
        if path.stat().st_size > 1 << 20:  # vehicle files are a few lines; a big file is data
            return None
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None


def hello_from_file(path, port_info: dict | None) -> tuple[dict, str]:
    """(HELLO document marked ``supplied_from``, a warning to print) from an earlier log."""
    from host.mcap_read import read_log

    path = check_source(path)
    doc = _toml(path)
    if doc is not None:
        hello = dict(_board_of(path, doc), supplied_from=f"{path} [board]")
        return hello, (f"no HELLO was received; its configuration is taken from the [board] table of {path}, "
                       "as declared there: nothing can check it against the board, and a wrong ADC scale, tick "
                       "modulus or channel converts every sample wrong (marked so in the file)")
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
