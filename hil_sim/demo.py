"""`make demo`: the simulated car, its firmware on an emulated serial port, stid-log
recording it, and the run exported in SI units."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

OUT = Path("demo_out")


def _tool(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def say(text: str) -> None:
    print(text, flush=True)


def log_over_pty(args: list[str], mcap: Path, seconds: float) -> None:
    sim = subprocess.Popen([_tool("stid-sim"), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = sim.stdout.readline().split(": ", 1)[1].strip()
    say(f"  simulated car on {port}: firmware running under MicroPython, streaming in real time")
    lg = subprocess.run([_tool("stid-log"), port, "-o", str(mcap), "--duration", str(seconds + 8),
                         "--reconnect-timeout", "0.5"], stderr=subprocess.PIPE, text=True)
    sim.wait()
    if lg.returncode != 0:
        raise SystemExit(f"demo: stid-log failed: {lg.stderr.strip()}")
    say("  " + lg.stderr.strip().splitlines()[-1])


def main() -> int:
    OUT.mkdir(exist_ok=True)
    t0 = time.time()
    mcap = OUT / "random_steer.mcap"
    say("1. Drive the simulated car (random steer, 4 m/s) and log it with stid-log over a pseudo-terminal")
    log_over_pty(["--manoeuvre", "random_steer", "--duration", "8", "--still", "1", "--seed", "1"], mcap, 12)
    say("2. Export the run in SI units (CSV import contract)")
    csv = OUT / "random_steer.csv"
    r = subprocess.run([_tool("stid"), "export", str(mcap), "--csv", str(csv)], stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        raise SystemExit(f"demo: export failed: {r.stderr.strip()}")
    say(f"  wrote {csv}")
    say(f"done in {time.time() - t0:.0f} s: {mcap} (open it in Foxglove), {csv}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
