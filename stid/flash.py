"""Put the firmware on a board: check the link budget, the board and its memory, stop
the running app, precompile with mpy-cross, copy with mpremote, verify.

The steps, in order (``plan`` lists them; ``--dry-run`` prints them as a shell script
that does the flash when run as printed):

1. Refuse a rate the link cannot carry: more than 80% of the line (the arithmetic
   is in the message), or a rate whose period is not a whole number of µs.
2. Compile every module with mpy-cross for the board's architecture and write
   ``config.py`` into the build folder.
3. Send the escape line (``app.ESCAPE``) on the port at the link's baud: a board
   running the app reboots into safe mode (Ctrl-C is disabled while it runs, and
   mpremote needs Ctrl-C to enter the raw REPL). firmware/README.md has the
   recovery by hand.
4. Ask the board (one script): ``sys.platform`` must be the ``--board``'s; MicroPython
   1.23 or newer (the ``.mpy`` format), 1.26 for the Pico's hard timer (a note);
   ``gc.mem_free()`` must hold the sample ring the rate needs plus the firmware; the
   filesystem must have room for the files.
5. Remove ``main.py`` and stale ``.py`` copies of the compiled modules (a ``.py``
   beside a ``.mpy`` is imported first). Without ``main.py`` the board boots to the
   REPL: a flash that stops half way leaves a board that can be flashed again.
6. Copy the modules and ``config.py``, compare the SHA-256 of each on the board with
   the build, then import the firmware on the board and read back its firmware and
   protocol versions (the ``.mpy`` files load there, and they are this build's).
7. Copy ``main.py`` last, verify it, reset.
"""

from __future__ import annotations

import ast
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
COMPILED_MODULES = ("codec", "ring", "pulses", "boards", "sampler", "adc_scan", "servo_pio", "servo_pcnt", "hall_pcnt",
                    "app")
ARCH = {"pico": "armv6m", "esp32": "xtensawin"}
PLATFORM = {"pico": "rp2", "esp32": "esp32"}  # sys.platform of each board's MicroPython port
ESCAPE = b"STID-ESCAPE"  # firmware/micropython/app.py ESCAPE
MIN_MICROPYTHON = (1, 23)  # .mpy version 6.3 (mpy-cross >= 1.23)
HARD_TIMER_MICROPYTHON = (1, 26)  # rp2 Timer(hard=True)
PCNT_MICROPYTHON = (1, 26)  # esp32.PCNT (commit c3f3339c87, first in v1.26.0): the ESP32's steering timer
LINE_BUDGET = 0.8  # most of the line a stream may use
RING_SECONDS = 1.25  # app.py: the default ring holds 1.25 s of samples (_RING_SECONDS_X4 = 5)
RING_INDEX_BYTES = 4  # ring.py: each slot also holds its sample index (array "i")
# What the firmware itself takes of the heap besides the ring: its modules' code and
# objects, frame buffers, the RP2040's DMA scan ring. Measured with App(ring_size=20) on
# the simulated board under the 64-bit MicroPython unix port (gc.mem_alloc: 67 kB for the
# Pico, 55 kB for the ESP32); a 32-bit board's objects are smaller, so this is a ceiling.
FIRMWARE_HEAP_BYTES = 68_000
FS_MARGIN_BYTES = 8192  # littlefs writes a file's new blocks before it frees the old ones


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


FIRMWARE_RATES = (10, 5000)  # Hz: what the firmware's App accepts (as stid-sim checks too)


def stream_bytes_per_s(rate_hz: int, batch: int, wheels: int = 1) -> float:
    return rate_hz * (RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch) + HOUSEKEEPING_BYTES_PER_S


def _whole_us_rates(most: int):
    return (r for r in range(most, 0, -1) if 1_000_000 % r == 0)


def check_link(board: str, rate_hz: int, batch: int, wheels: int = 1) -> str:
    """The link budget in one line; raises StidError when the rate does not fit."""
    lo, hi = FIRMWARE_RATES
    if not lo <= rate_hz <= hi:  # (the firmware's App refuses it at boot: the board would sit at the REPL)
        raise StidError(f"--rate {rate_hz} Hz: the firmware samples at {lo} to {hi} Hz (firmware/micropython/app.py); "
                        "try 200, 250, 400, 500, 625, 800 or 1000")
    if rate_hz <= 0 or 1_000_000 % rate_hz:
        raise StidError(f"--rate {rate_hz} Hz: the sample period must be a whole number of µs "
                        "(1000000 divisible by the rate): try 200, 250, 400, 500, 625, 800 or 1000")
    if wheels not in RECORD_SIZE:
        raise StidError(f"--wheels {wheels}: the firmware reads one hall sensor or four")
    if not 1 <= batch <= (38 if wheels == 1 else 22):
        raise StidError(f"--batch {batch}: must be 1..{38 if wheels == 1 else 22} samples per frame "
                        f"with {wheels} hall sensor{'s' if wheels > 1 else ''}")
    link = LINKS[board]
    need = stream_bytes_per_s(rate_hz, batch, wheels)
    share = need / link.bytes_per_s
    line = (f"{rate_hz} Hz x {RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch:.1f} B/sample + "
            f"{HOUSEKEEPING_BYTES_PER_S:.0f} B/s HELLO/STATUS = {need / 1000:.1f} kB/s on {link.describe()} "
            f"({link.bytes_per_s / 1000:.1f} kB/s): {100 * share:.0f}% of the line")
    if share > LINE_BUDGET:
        most = int((LINE_BUDGET * link.bytes_per_s - HOUSEKEEPING_BYTES_PER_S)
                   / (RECORD_SIZE[wheels] + FRAME_OVERHEAD / batch))
        most = next(_whole_us_rates(most), 1)  # the highest rate that fits and has a whole-µs period
        raise StidError(f"{line}, more than {100 * LINE_BUDGET:.0f}%: samples would be lost. "
                        f"Use --rate {most} or less.")
    return line


def ring_bytes(rate_hz: int, batch: int, wheels: int = 1) -> int:
    """Heap the firmware's default sample ring takes (app.py: 1.25 s, at least two frames)."""
    slots = max(2 * batch, rate_hz * 5 // 4)
    return slots * (RECORD_SIZE[wheels] + RING_INDEX_BYTES)


def check_heap(rate_hz: int, batch: int, wheels: int, mem_free: int) -> str:
    """The RAM budget in one line; raises StidError when the ring does not fit the heap
    the board reported (gc.mem_free() at its REPL, what main.py starts the app with)."""
    ring = ring_bytes(rate_hz, batch, wheels)
    need = ring + FIRMWARE_HEAP_BYTES
    line = (f"ring of {RING_SECONDS:g} s = {max(2 * batch, rate_hz * 5 // 4)} samples x "
            f"{RECORD_SIZE[wheels] + RING_INDEX_BYTES} B = {ring / 1000:.1f} kB + firmware "
            f"{FIRMWARE_HEAP_BYTES / 1000:.0f} kB = {need / 1000:.1f} kB of the board's {mem_free / 1000:.1f} kB "
            "free heap")
    if need > mem_free:
        most = next((r for r in _whole_us_rates(rate_hz)
                     if ring_bytes(r, batch, wheels) + FIRMWARE_HEAP_BYTES <= mem_free), None)
        advice = f"Use --rate {most} or less." if most else "Free memory on the board (remove boot.py extras)."
        raise StidError(f"{line}: does not fit, the firmware would stop with MemoryError. {advice}")
    return line


def _tool(name: str) -> str:
    here = Path(sys.executable).parent / name
    if here.exists():
        return str(here)
    found = shutil.which(name)
    if not found:
        raise ToolMissing(f"'{name}' is not installed: run 'make venv' or 'pip install {name}'")
    return found


def config_text(board: str, rate_hz: int, batch: int, wheels: int = 1) -> str:
    text = f"# written by 'stid flash'\nBOARD = {board!r}\nRATE_HZ = {rate_hz}\nBATCH = {batch}\n"
    if wheels == 4:
        text += "WHEELS = 4\n"  # the profile's four hall sensors (boards.py wheel_pins4)
    return text


def local_versions() -> tuple[tuple[int, int, int], int]:
    """(firmware version, protocol version) of this build, read from the sources."""
    def assigned(module: str, name: str):
        tree = ast.parse((FIRMWARE_DIR / f"{module}.py").read_text())
        node = next(n.value for n in tree.body if isinstance(n, ast.Assign)
                    and getattr(n.targets[0], "id", "") == name)
        if isinstance(node, ast.Call):  # VERSION = const(3)
            node = node.args[0]
        return ast.literal_eval(node)

    return tuple(assigned("app", "FW_VERSION")), int(assigned("codec", "VERSION"))


# -- what runs on the board (mpremote exec) ----------------------------------------------
# (double quotes only: the printed plan quotes each script in single quotes)
PROBE_SCRIPT = ('import sys, gc, os\ngc.collect()\ntry:\n s = os.statvfs("/")\n fs = s[0] * s[4]\n'
                'except (AttributeError, OSError):\n fs = -1\n'
                'print("STIDVER", *sys.implementation.version[:3], sys.platform)\n'
                'print("STIDMEM", gc.mem_free(), fs)\n')
READBACK_SCRIPT = 'import app, codec\nprint("STIDFW", *app.FW_VERSION, codec.VERSION)\n'


def _names(names) -> str:
    return ", ".join(f'"{n}"' for n in names)


def _prepare_script() -> str:
    # main.py first: from here until it is copied back the board boots to the REPL
    return ("import os\nfor f in (" + _names(m + ".py" for m in ("main",) + COMPILED_MODULES) + "):\n"
            ' try:\n  os.remove(f); print("STIDRM", f)\n except OSError:\n  pass\n')


def _hash_script(names) -> str:
    return ("import hashlib, binascii\nfor f in (" + _names(names) + ",):\n"
            ' h = hashlib.sha256()\n with open(f, "rb") as fh:\n  h.update(fh.read())\n'
            ' print("STIDSHA", f, binascii.hexlify(h.digest()).decode())\n')


@dataclass(frozen=True)
class BoardFacts:
    version: tuple[int, int, int]
    platform: str
    mem_free: int
    fs_free: int  # bytes; -1 when the board did not say


def parse_probe(text: str, board: str, port: str | None) -> BoardFacts:
    """The board's answer to PROBE_SCRIPT; refuses another board or a garbled answer."""
    ver = re.search(r"^STIDVER (\d+) (\d+) (\d+) (\S+)\s*$", text, re.M)
    mem = re.search(r"^STIDMEM (\d+) (-?\d+)\s*$", text, re.M)
    where = port or "the port mpremote found"
    if not ver or not mem:
        shown = text.strip()[:80]
        raise StidError(f"the board on {where} did not answer the version probe as MicroPython does "
                        f"(got {shown!r}). Is MicroPython on it, and no other program on the port? "
                        "Reset the board and try again; firmware/README.md, 'Recovery', if the app "
                        "keeps running. Nothing was written to the board.")
    platform = ver.group(4)
    if platform != PLATFORM[board]:
        other = next((b for b, p in PLATFORM.items() if p == platform), None)
        fix = f"use --board {other}" if other else "stid supports " + ", ".join(PLATFORM)
        raise StidError(f"the board on {where} runs MicroPython for {platform!r} (sys.platform), not a "
                        f"{board} ({PLATFORM[board]!r}): {fix}. Nothing was written to the board.")
    return BoardFacts(tuple(int(x) for x in ver.groups()[:3]), platform, int(mem.group(1)), int(mem.group(2)))


def check_micropython(version: tuple[int, int, int], board: str) -> str:
    """Refuse below 1.23; return a note ("" if none)."""
    shown = ".".join(map(str, version))
    if version[:2] < MIN_MICROPYTHON:
        raise StidError(f"the board runs MicroPython {shown}; the compiled firmware (.mpy 6.3) needs "
                        f"{'.'.join(map(str, MIN_MICROPYTHON))} or newer: update MicroPython on the board.")
    if board == "pico" and version[:2] < HARD_TIMER_MICROPYTHON:
        return (f"note: MicroPython {shown} has no hard timers on rp2 (1.26+): the sampler runs "
                "scheduled, so samples are late by up to a frame write and some periods may be "
                "missed (counted in STATUS `missed`; HELLO says timer 'soft'). Update for fixed-rate sampling.")
    if board == "esp32" and version[:2] < PCNT_MICROPYTHON:
        return (f"note: MicroPython {shown} has no esp32.PCNT (1.26+): the steering pulses are timed by "
                "scheduled pin callbacks, late by up to a frame write and some lost (HELLO without "
                "capture.servo 'pcnt'; stid notes it). Update for steering timed to ±1 µs.")
    return ""


def check_filesystem(fs_free: int, files: list[Path]) -> None:
    need = sum(f.stat().st_size for f in files) + FS_MARGIN_BYTES
    if 0 <= fs_free < need:
        raise StidError(f"the board's filesystem has {fs_free / 1000:.1f} kB free, the firmware needs "
                        f"{need / 1000:.1f} kB: remove files you do not need "
                        "('mpremote fs ls', 'mpremote fs rm FILE') and flash again. Nothing was written.")


def verify(text: str, files: list[Path]) -> None:
    got = dict(re.findall(r"STIDSHA (\S+) ([0-9a-f]{64})", text))
    bad = [f.name for f in files if got.get(f.name) != hashlib.sha256(f.read_bytes()).hexdigest()]
    if bad:
        raise StidError(f"the copy on the board differs from the build for {', '.join(bad)}: "
                        "flash again; if it persists the board's filesystem may be full or damaged.")


def check_readback(text: str) -> None:
    m = re.search(r"^STIDFW (\d+) (\d+) (\d+) (\d+)\s*$", text, re.M)
    fw, proto = local_versions()
    want = "firmware %d.%d.%d, protocol %d" % (*fw, proto)
    if not m:
        shown = text.strip().splitlines()[-1:] or ["nothing"]
        raise StidError(f"the firmware copied to the board does not import there ({shown[0][:100]}); "
                        f"expected {want}. main.py is not on the board yet, so it boots to the REPL: "
                        "flash again; if it persists, report it with the board's MicroPython version.")
    got = tuple(int(x) for x in m.groups())
    if got != (*fw, proto):
        raise StidError("the board reports firmware %d.%d.%d, protocol %d after the copy; " % got
                        + f"this build is {want}: flash again (a stale file on the board?).")


# -- the plan ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Step:
    kind: str  # compile, config, escape, probe, prepare, copy, hash, readback, copy_main, hash_main, reset
    cmd: list[str]


def _connect(port: str | None) -> list[str]:
    return ["connect", port] if port else ["connect", "auto"]


def _escape_cmd(port: str, board: str) -> list[str]:
    code = (f"import serial, time; s = serial.Serial({port!r}, {LINKS[board].baud or 115200}); "
            f"s.write(b'\\r\\n' + {ESCAPE!r} + b'\\r\\n'); s.flush(); s.close(); time.sleep(2.5)")
    return [sys.executable, "-c", code]


def plan(board: str, port: str | None, build_dir: Path, rate_hz: int, batch: int, wheels: int = 1) -> list[Step]:
    """The commands a flash runs, in order."""
    if board not in ARCH:
        raise StidError(f"unknown board {board!r}: choose one of {', '.join(ARCH)}")
    mpremote = [_tool("mpremote"), *_connect(port)]
    steps = [Step("compile", [_tool("mpy-cross"), f"-march={ARCH[board]}", "-o", str(build_dir / f"{m}.mpy"),
                              str(FIRMWARE_DIR / f"{m}.py")]) for m in COMPILED_MODULES]
    steps.append(Step("config", []))
    if port:
        steps.append(Step("escape", _escape_cmd(port, board)))
    steps.append(Step("probe", [*mpremote, "exec", PROBE_SCRIPT]))
    steps.append(Step("prepare", [*mpremote, "exec", _prepare_script()]))
    files = [str(build_dir / f"{m}.mpy") for m in COMPILED_MODULES] + [str(build_dir / "config.py")]
    steps.append(Step("copy", [*mpremote, "fs", "cp", *files, ":"]))
    steps.append(Step("hash", [*mpremote, "exec", _hash_script([Path(f).name for f in files])]))
    steps.append(Step("readback", [*mpremote, "exec", READBACK_SCRIPT]))
    steps.append(Step("copy_main", [*mpremote, "fs", "cp", str(FIRMWARE_DIR / "main.py"), ":"]))
    steps.append(Step("hash_main", [*mpremote, "exec", _hash_script(["main.py"])]))
    steps.append(Step("reset", [*mpremote, "reset"]))
    return steps


def plan_script(board: str, port: str | None, build_dir: Path, rate_hz: int, batch: int, wheels: int,
                budget: str) -> str:
    """The plan as a shell script that flashes the board when run as printed, and checks the
    board's answers as stid flash does: another board, an old MicroPython, too little heap or
    flash, a copy that differs from the build or firmware that does not import there stop it
    with the same advice, before main.py is copied."""
    fw, proto = local_versions()
    ring = ring_bytes(rate_hz, batch, wheels) + FIRMWARE_HEAP_BYTES
    build = shlex.quote(str(build_dir))
    files = [f"{m}.mpy" for m in COMPILED_MODULES] + ["config.py"]
    platform, (major, minor) = PLATFORM[board], MIN_MICROPYTHON
    want_fw = "STIDFW %d %d %d %d" % (*fw, proto)
    lines = [f"#!/bin/sh\n# stid flash: {board} ({ARCH[board]}), {rate_hz} Hz, {batch} samples per frame, "
             f"{wheels} hall sensor{'s' if wheels > 1 else ''}",
             f"# link: {budget}", "set -e",
             'fail() { echo "stid flash: $*" >&2; exit 1; }',
             "# what the board printed, without its carriage returns",
             # (under set -e a failed command would end the script in its own words alone: say what stid
             # flash says then)
             'ask() { answer=$("$@" 2>&1) || fail "\'$(basename "$1") $2 $3\' failed ($(printf \'%s\\n\' "$answer" | '
             'tail -n 1)). Is the board plugged in and the port right? Try --port /dev/ttyACM0. If the app runs and '
             'does not answer, see firmware/README.md, \'Recovery\'."; answer=$(printf \'%s\\n\' "$answer" | '
             'tr -d \'\\r\'); printf \'%s\\n\' "$answer"; }',
             'sha() { if command -v sha256sum >/dev/null; then sha256sum "$1"; else shasum -a 256 "$1"; fi | cut -d" " -f1; }',
             shlex.join(["mkdir", "-p", str(build_dir)])]
    if not port:
        lines.append("# no --port: no escape is sent; if the app is running, mpremote cannot stop it "
                     "(firmware/README.md, 'Recovery')")
    checks = {
        "probe": [
            f"printf '%s\\n' \"$answer\" | grep -Eq '^STIDVER [0-9]+ [0-9]+ [0-9]+ {platform}$' || "
            f"fail \"the board's answer has no 'STIDVER ... {platform}' line: it is not a {board} (sys.platform "
            f"{platform}), or it did not answer: give the right --board, or see firmware/README.md, 'Recovery'\"",
            f"printf '%s\\n' \"$answer\" | awk '/^STIDVER/ {{ok = $2 > {major} || ($2 == {major} && $3 >= {minor})}} "
            f"END {{exit !ok}}' || fail \"the compiled firmware (.mpy 6.3) needs MicroPython {major}.{minor} or "
            f"newer: update MicroPython on the board\"",
            f"printf '%s\\n' \"$answer\" | awk '/^STIDMEM/ {{ok = $2 >= {ring}}} END {{exit !ok}}' || "
            f"fail \"the board's free heap is below the {ring} B the ring of {rate_hz} Hz and the firmware need: "
            f"flash with a lower --rate\"",
            f"need=$(( $(cat {' '.join(f'{build}/{f}' for f in files)} {shlex.quote(str(FIRMWARE_DIR / 'main.py'))} "
            f"| wc -c) + {FS_MARGIN_BYTES} ))",
            "printf '%s\\n' \"$answer\" | awk -v need=\"$need\" '/^STIDMEM/ {ok = $3 < 0 || $3 >= need} "
            "END {exit !ok}' || fail \"the board's filesystem has less room than the firmware's $need B: remove "
            "files you do not need ('mpremote fs ls', 'mpremote fs rm FILE'). Nothing was written.\""],
        "hash": [f"for f in {' '.join(files)}; do",
                 f"  printf '%s\\n' \"$answer\" | grep -qx \"STIDSHA $f $(sha {build}/$f)\" || "
                 "fail \"the copy on the board differs from the build for $f: flash again\"",
                 "done"],
        "readback": [f"printf '%s\\n' \"$answer\" | grep -qx '{want_fw}' || fail \"the firmware copied to the board "
                     f"does not import there, or is not this build's ({want_fw}); main.py is not on the board yet: "
                     "flash again\""],
        "hash_main": [f"printf '%s\\n' \"$answer\" | grep -qx \"STIDSHA main.py "
                      f"$(sha {shlex.quote(str(FIRMWARE_DIR / 'main.py'))})\" || "
                      "fail \"the copy of main.py on the board differs from the firmware's: flash again\""],
    }
    notes = {"prepare": "main.py goes first: until it is copied back the board boots to the REPL",
             "escape": "a running app reboots into safe mode"}
    for step in plan(board, port, build_dir, rate_hz, batch, wheels):
        if step.kind == "config":
            lines.append(f"cat > {shlex.quote(str(build_dir / 'config.py'))} <<'STID_CONFIG'")
            lines.extend(config_text(board, rate_hz, batch, wheels).splitlines())
            lines.append("STID_CONFIG")
            continue
        if step.kind in notes:
            lines.append(f"# {notes[step.kind]}")
        if step.kind in checks:
            lines.append("ask " + shlex.join(step.cmd))
            lines.extend(checks[step.kind])
        else:
            lines.append(shlex.join(step.cmd))
    return "\n".join(lines) + "\n"


# -- running it ------------------------------------------------------------------------------
def _run(cmd: list[str]) -> str:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise _Failed(cmd, (proc.stderr or proc.stdout).strip())
    return proc.stdout


class _Failed(Exception):
    def __init__(self, cmd, output):
        super().__init__(output)
        self.cmd = cmd
        self.output = output

    def detail(self) -> str:
        return (self.output.splitlines()[-1:] or ["no output"])[0]


def _link_error(e: _Failed) -> StidError:
    return StidError(f"'{Path(e.cmd[0]).name} {' '.join(e.cmd[1:3])}' failed ({e.detail()}). "
                     "Is the board plugged in and the port right? Try --port /dev/ttyACM0. "
                     "If the app runs and does not answer, see firmware/README.md, 'Recovery'.")


def _copy_error(e: _Failed) -> StidError:
    if re.search(r"ENOSPC|No space left|Errno 28", e.output):
        return StidError("the board's filesystem is full: the copy stopped half way. main.py was removed "
                         "first, so the board boots to the REPL: remove files you do not need "
                         "('mpremote fs ls', 'mpremote fs rm FILE') and flash again.")
    return StidError(f"the copy stopped half way ({e.detail()}). main.py was removed first, so the "
                     "board boots to the REPL and can be flashed again: check the cable and run "
                     "the same stid flash command.")


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


def flash(board: str, port: str | None = None, dry_run: bool = False, rate_hz: int = 500,
          batch: int = 10, wheels: int = 1, build_dir: Path | None = None, out=None) -> int:
    out = out or sys.stdout
    if board not in ARCH:
        raise StidError(f"unknown board {board!r}: choose one of {', '.join(ARCH)}")
    budget = check_link(board, rate_hz, batch, wheels)
    if dry_run:
        # a folder that outlives the command: the printed plan is run later, as printed
        build_dir = Path(build_dir or f"stid-flash-{board}").resolve()
        out.write(plan_script(board, port, build_dir, rate_hz, batch, wheels, budget))
        return 0
    keep = build_dir is not None
    build_dir = Path(build_dir) if keep else Path(tempfile.mkdtemp(prefix="stid-flash-"))
    build_dir.mkdir(parents=True, exist_ok=True)
    steps = {s.kind: s for s in plan(board, port, build_dir, rate_hz, batch, wheels)}
    print(f"# firmware for {board} ({ARCH[board]}), {rate_hz} Hz, {batch} samples per frame, "
          f"{wheels} hall sensor{'s' if wheels > 1 else ''}", file=out)
    print(f"# link: {budget}", file=out)
    try:
        for step in plan(board, port, build_dir, rate_hz, batch, wheels):
            if step.kind == "compile":
                try:
                    _run(step.cmd)
                except _Failed as e:
                    raise StidError(f"mpy-cross could not compile {Path(step.cmd[-1]).name}: {e.detail()}") from None
        (build_dir / "config.py").write_text(config_text(board, rate_hz, batch, wheels))
        files = [build_dir / f"{m}.mpy" for m in COMPILED_MODULES] + [build_dir / "config.py"]
        main_py = FIRMWARE_DIR / "main.py"
        if port:
            send_escape(port, board)
        try:
            facts = parse_probe(_run(steps["probe"].cmd), board, port)
        except _Failed as e:
            raise _link_error(e) from None
        note = check_micropython(facts.version, board)
        if note:
            print(note, file=out)
        print(f"# heap: {check_heap(rate_hz, batch, wheels, facts.mem_free)}", file=out)
        check_filesystem(facts.fs_free, files + [main_py])
        try:
            _run(steps["prepare"].cmd)
        except _Failed as e:
            raise _link_error(e) from None
        for copy, check in (("copy", "hash"), ("copy_main", "hash_main")):
            try:
                _run(steps[copy].cmd)
            except _Failed as e:
                raise _copy_error(e) from None
            try:
                verify(_run(steps[check].cmd), files if copy == "copy" else [main_py])
            except _Failed as e:
                raise _copy_error(e) from None
            if copy == "copy":
                try:
                    check_readback(_run(steps["readback"].cmd))
                except _Failed as e:
                    check_readback(e.output)  # the import's error, in the message
        try:
            _run(steps["reset"].cmd)
        except _Failed as e:
            raise _link_error(e) from None
    finally:
        if not keep:
            shutil.rmtree(build_dir, ignore_errors=True)
    fw, proto = local_versions()
    print("flashed %s: firmware %d.%d.%d, protocol %d read back, copies verified (SHA-256); "
          "the firmware starts on reset" % (board, *fw, proto), file=out)
    return 0
