"""Put the firmware on a board: check the link budget and the board's MicroPython,
stop the running app, precompile with mpy-cross, copy with mpremote, verify.

The steps, in order (``plan`` lists the commands, ``--dry-run`` prints them):

1. Refuse a rate the link cannot carry: more than 80% of the line (the arithmetic
   is in the message), or a rate whose period is not a whole number of µs.
2. Send the escape line (``app.ESCAPE``) on the port at the link's baud: a board
   running the app reboots into safe mode (Ctrl-C is disabled while it runs, and
   mpremote needs Ctrl-C to enter the raw REPL). firmware/README.md has the
   recovery by hand.
3. Ask the board for ``sys.implementation``: refuse below MicroPython 1.23 (the
   ``.mpy`` format mpy-cross writes), warn below 1.26 (no hard timer on rp2).
4. Compile, remove stale ``.py`` copies of the compiled modules (a ``.py`` beside
   a ``.mpy`` is imported first), copy, compare SHA-256 of every file on the
   board with the local one, reset.
"""

from __future__ import annotations

import hashlib
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from stid.errors import StidError, ToolMissing

FIRMWARE_DIR = Path(__file__).resolve().parents[1] / "firmware" / "micropython"
# main.py stays source (the board boots it by name); config.py is written per flash.
COMPILED_MODULES = ("codec", "ring", "pulses", "boards", "sampler", "adc_scan", "servo_pio", "servo_pcnt", "app")
ARCH = {"pico": "armv6m", "esp32": "xtensawin"}
ESCAPE = b"STID-ESCAPE"  # firmware/micropython/app.py ESCAPE
MIN_MICROPYTHON = (1, 23)  # .mpy version 6.3 (mpy-cross >= 1.23)
HARD_TIMER_MICROPYTHON = (1, 26)  # rp2 Timer(hard=True)
LINE_BUDGET = 0.8  # most of the line a stream may use


@dataclass(frozen=True)
class Link:
    """A board's output link as the firmware sets it (boards.py PROFILES[...]["link"])."""

    kind: str  # "usb" or "uart"
    baud: int | None  # UART baud; None for USB-CDC
    bytes_per_s: float  # what the line carries

    def describe(self) -> str:
        return f"UART at {self.baud} baud" if self.kind == "uart" else "USB-CDC"


# USB full-speed CDC moves 7-9 Mbit/s on the RP2040; 1 MB/s is a safe floor.
# A UART byte is 10 bits (start, 8 data, stop).
LINKS = {"pico": Link("usb", None, 1_000_000.0), "esp32": Link("uart", 921_600, 921_600 / 10)}
RECORD_SIZE = {1: 26, 4: 44}  # bytes per sample record: one hall sensor, four
FRAME_OVERHEAD = 21  # header 10 + samples head 5 + CRC 4 + COBS code and delimiter 2
HOUSEKEEPING_BYTES_PER_S = 2 * 80 + 50 + 850 / 10  # compact HELLO + STATUS each second, full HELLO every 10 s


def stream_bytes_per_s(rate_hz: int, batch: int, wheels: int = 1) -> float:
    return rate_hz * (RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch) + HOUSEKEEPING_BYTES_PER_S


def check_link(board: str, rate_hz: int, batch: int, wheels: int = 1) -> str:
    """The link budget in one line; raises StidError when the rate does not fit."""
    if rate_hz <= 0 or 1_000_000 % rate_hz:
        raise StidError(f"--rate {rate_hz} Hz: the sample period must be a whole number of µs "
                        "(1000000 divisible by the rate): try 200, 250, 400, 500, 625, 800 or 1000")
    if not 1 <= batch <= (38 if wheels == 1 else 22):
        raise StidError(f"--batch {batch}: must be 1..{38 if wheels == 1 else 22} samples per frame")
    link = LINKS[board]
    need = stream_bytes_per_s(rate_hz, batch, wheels)
    share = need / link.bytes_per_s
    line = (f"{rate_hz} Hz x {RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch:.1f} B/sample + "
            f"{HOUSEKEEPING_BYTES_PER_S:.0f} B/s HELLO/STATUS = {need / 1000:.1f} kB/s on {link.describe()} "
            f"({link.bytes_per_s / 1000:.1f} kB/s): {100 * share:.0f}% of the line")
    if share > LINE_BUDGET:
        most = int((LINE_BUDGET * link.bytes_per_s - HOUSEKEEPING_BYTES_PER_S)
                   / (RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch))
        most = max((r for r in range(1, most + 1) if 1_000_000 % r == 0), default=1)  # a whole-µs period
        raise StidError(f"{line}, more than {100 * LINE_BUDGET:.0f}%: samples would be lost. "
                        f"Use --rate {most} or less.")
    return line


def _tool(name: str) -> str:
    here = Path(sys.executable).parent / name
    if here.exists():
        return str(here)
    found = shutil.which(name)
    if not found:
        raise ToolMissing(f"'{name}' is not installed: run 'make venv' or 'pip install {name}'")
    return found


def config_text(board: str, rate_hz: int, batch: int) -> str:
    return (f"# written by 'stid flash'\nBOARD = {board!r}\nRATE_HZ = {rate_hz}\nBATCH = {batch}\n")


_VERSION_SCRIPT = "import sys; print('STIDVER', *sys.implementation.version[:3], sys.platform)"


def _cleanup_script() -> str:
    names = ", ".join(repr(m + ".py") for m in COMPILED_MODULES)
    return ("import os\nfor f in (" + names + "):\n try:\n  os.remove(f); print('STIDRM', f)\n"
            " except OSError:\n  pass\n")


def _hash_script(names) -> str:
    return ("import hashlib, binascii\nfor f in (" + ", ".join(repr(n) for n in names) + ",):\n"
            " h = hashlib.sha256()\n with open(f, 'rb') as fh:\n  h.update(fh.read())\n"
            " print('STIDSHA', f, binascii.hexlify(h.digest()).decode())\n")


def plan(board: str, port: str | None, build_dir: Path, rate_hz: int, batch: int) -> list[list[str]]:
    """The exact commands a flash runs, in order (the escape and version check come first)."""
    if board not in ARCH:
        raise StidError(f"unknown board {board!r}: choose one of {', '.join(ARCH)}")
    cmds = []
    for mod in COMPILED_MODULES:
        cmds.append([_tool("mpy-cross"), f"-march={ARCH[board]}", "-o", str(build_dir / f"{mod}.mpy"),
                     str(FIRMWARE_DIR / f"{mod}.py")])
    connect = ["connect", port] if port else ["connect", "auto"]
    mpremote = _tool("mpremote")
    cmds.append([mpremote, *connect, "exec", _cleanup_script()])
    files = [str(build_dir / f"{m}.mpy") for m in COMPILED_MODULES]
    files += [str(FIRMWARE_DIR / "main.py"), str(build_dir / "config.py")]
    cmds.append([mpremote, *connect, "fs", "cp", *files, ":"])
    cmds.append([mpremote, *connect, "exec", _hash_script([Path(f).name for f in files])])
    cmds.append([mpremote, *connect, "reset"])
    return cmds


def _run(cmd: list[str]) -> str:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        detail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise StidError(f"'{Path(cmd[0]).name} {cmd[1]}' failed ({detail[0]}). "
                        "Is the board plugged in and the port right? Try --port /dev/ttyACM0. "
                        "If the app runs and does not answer, see firmware/README.md, 'Recovery'.")
    return proc.stdout


def send_escape(port: str, board: str) -> None:
    """Ask a running app to reboot into safe mode (harmless at a REPL: mpremote's Ctrl-C
    clears the typed line). Then wait for the reboot."""
    import serial

    link = LINKS[board]
    try:
        with serial.Serial(port, baudrate=link.baud or 115200, timeout=0.2) as s:
            s.write(b"\r\n" + ESCAPE + b"\r\n")
            s.flush()
    except (serial.SerialException, OSError) as e:
        raise StidError(f"cannot open {port} ({e}). Is the board plugged in and the port right?") from None
    time.sleep(2.5)  # reset, main.py's 1 s window, safe boot


def check_micropython(text: str, board: str) -> tuple[tuple[int, int, int], str]:
    """Parse the board's answer; refuse below 1.23; return (version, note)."""
    m = re.search(r"STIDVER (\d+) (\d+) (\d+) (\w+)", text)
    if not m:
        raise StidError("the board did not report its MicroPython version: is it running MicroPython? "
                        "Flash MicroPython first (https://micropython.org/download/).")
    ver = tuple(int(x) for x in m.groups()[:3])
    shown = ".".join(map(str, ver))
    if ver[:2] < MIN_MICROPYTHON:
        raise StidError(f"the board runs MicroPython {shown}; the compiled firmware (.mpy 6.3) needs "
                        f"{'.'.join(map(str, MIN_MICROPYTHON))} or newer: update MicroPython on the board.")
    note = ""
    if board == "pico" and ver[:2] < HARD_TIMER_MICROPYTHON:
        note = (f"note: MicroPython {shown} has no hard timers on rp2 (1.26+): the sampler runs "
                "scheduled, so samples are late by up to a frame write and some periods may be "
                "missed (counted in STATUS `missed`; HELLO says timer 'soft'). Update for fixed-rate sampling.")
    return ver, note


def verify(text: str, files: list[Path]) -> None:
    got = dict(re.findall(r"STIDSHA (\S+) ([0-9a-f]{64})", text))
    bad = [f.name for f in files if got.get(f.name) != hashlib.sha256(f.read_bytes()).hexdigest()]
    if bad:
        raise StidError(f"the copy on the board differs from the build for {', '.join(bad)}: "
                        "flash again; if it persists the board's filesystem may be full or damaged.")


def flash(board: str, port: str | None = None, dry_run: bool = False, rate_hz: int = 500,
          batch: int = 10, out=None) -> int:
    out = out or sys.stdout
    if board not in ARCH:
        raise StidError(f"unknown board {board!r}: choose one of {', '.join(ARCH)}")
    budget = check_link(board, rate_hz, batch)
    build_dir = Path(tempfile.mkdtemp(prefix="stid-flash-"))
    cmds = plan(board, port, build_dir, rate_hz, batch)
    connect = ["connect", port] if port else ["connect", "auto"]
    print(f"# firmware for {board} ({ARCH[board]}), {rate_hz} Hz, {batch} samples per frame", file=out)
    print(f"# link: {budget}", file=out)
    if port:
        print(f"# send {ESCAPE.decode()!r} on {port} at {LINKS[board].baud or 'any'} baud (a running app "
              "reboots into safe mode)", file=out)
    else:
        print("# no --port: no escape is sent; if the app is running, mpremote cannot stop it "
              "(firmware/README.md, 'Recovery')", file=out)
    print(f"# ask the board: {shlex.join([_tool('mpremote'), *connect, 'exec', _VERSION_SCRIPT])}", file=out)
    print(f"# write {build_dir / 'config.py'}:", file=out)
    for line in config_text(board, rate_hz, batch).splitlines():
        print(f"#   {line}", file=out)
    for cmd in cmds:
        print(shlex.join(cmd), file=out)
    if dry_run:
        shutil.rmtree(build_dir, ignore_errors=True)
        return 0
    try:
        if port:
            send_escape(port, board)
        _, note = check_micropython(_run([_tool("mpremote"), *connect, "exec", _VERSION_SCRIPT]), board)
        if note:
            print(note, file=out)
        (build_dir / "config.py").write_text(config_text(board, rate_hz, batch))
        for cmd in cmds[:-2]:
            _run(cmd)
        files = [build_dir / f"{m}.mpy" for m in COMPILED_MODULES] + [FIRMWARE_DIR / "main.py",
                                                                       build_dir / "config.py"]
        verify(_run(cmds[-2]), files)
        _run(cmds[-1])
    finally:
        shutil.rmtree(build_dir, ignore_errors=True)
    print(f"flashed {board}, copies verified (SHA-256); the firmware starts on reset", file=out)
    return 0
