"""Put the firmware on a board: precompile with mpy-cross, copy with mpremote."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from stid.errors import StidError, ToolMissing

FIRMWARE_DIR = Path(__file__).resolve().parents[1] / "firmware" / "micropython"
# main.py stays source (the board boots it by name); config.py is written per flash.
COMPILED_MODULES = ("codec", "ring", "pulses", "boards", "sampler", "app")
ARCH = {"pico": "armv6m", "esp32": "xtensawin"}


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


def plan(board: str, port: str | None, build_dir: Path, rate_hz: int, batch: int) -> list[list[str]]:
    """The exact commands a flash runs, in order."""
    if board not in ARCH:
        raise StidError(f"unknown board {board!r}: choose one of {', '.join(ARCH)}")
    cmds = []
    for mod in COMPILED_MODULES:
        cmds.append([_tool("mpy-cross"), f"-march={ARCH[board]}", "-o", str(build_dir / f"{mod}.mpy"),
                     str(FIRMWARE_DIR / f"{mod}.py")])
    connect = ["connect", port] if port else ["connect", "auto"]
    files = [str(build_dir / f"{m}.mpy") for m in COMPILED_MODULES]
    files += [str(FIRMWARE_DIR / "main.py"), str(build_dir / "config.py")]
    cmds.append([_tool("mpremote"), *connect, "fs", "cp", *files, ":"])
    cmds.append([_tool("mpremote"), *connect, "reset"])
    return cmds


def flash(board: str, port: str | None = None, dry_run: bool = False, rate_hz: int = 500,
          batch: int = 10, out=None) -> int:
    out = out or sys.stdout
    build_dir = Path(tempfile.mkdtemp(prefix="stid-flash-"))
    cmds = plan(board, port, build_dir, rate_hz, batch)
    print(f"# firmware for {board} ({ARCH[board]}), {rate_hz} Hz, {batch} samples per frame", file=out)
    print(f"# write {build_dir / 'config.py'}:", file=out)
    for line in config_text(board, rate_hz, batch).splitlines():
        print(f"#   {line}", file=out)
    for cmd in cmds:
        print(shlex.join(cmd), file=out)
    if dry_run:
        shutil.rmtree(build_dir, ignore_errors=True)
        return 0
    (build_dir / "config.py").write_text(config_text(board, rate_hz, batch))
    for cmd in cmds:
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            detail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            raise StidError(f"'{Path(cmd[0]).name} {cmd[1]}' failed ({detail[0]}). "
                            "Is the board plugged in and the port right? Try --port /dev/ttyACM0.")
    shutil.rmtree(build_dir, ignore_errors=True)
    print(f"flashed {board}; the firmware starts on reset", file=out)
    return 0
