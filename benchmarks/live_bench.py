"""The live view's update, as a user meets it: ``stid live RUN --follow`` (its own process)
follows a run that grows to 5 minutes of 500 Hz data; the updates after each growth of the
file are measured (warm: each follows an update on the file before), by the CPU seconds
the view reports for them (reading the file included) and the wall time from the file's
growth to the update's line.

The run is the simulated car on a track (speed +-25% around 4 m/s, the servo lag hidden),
written by ``stid-sim --fast``; what a reader of a file stid-log is writing sees is a byte
prefix of it, so the growth is a byte prefix followed by the rest.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

RATE_HZ = 500


def _run(d: Path, minutes: float) -> Path:
    path = d / f"live_track_{minutes:g}min.mcap"
    if not path.exists():
        subprocess.run([str(Path(sys.executable).parent / "stid-sim"), "--fast", "-o", str(path), "--duration",
                        str(60 * minutes), "--speed", "4", "--speed-profile", "track", "--effects", "actuator_lag",
                        "--seed", "11", "--overwrite"], check=True, capture_output=True)
    return path


def update_cost(d: Path, model: str, quick: bool, steps: int = 4) -> dict:
    """CPU and wall time of warm live updates on 5 min (quick: 1 min) of 500 Hz data: the
    file grows from 94% to all of it in ``steps`` steps (about 4 s of driving each, two
    updates' worth at stid live's default pace); the median and the largest update."""
    minutes = 1.0 if quick else 5.0
    d.mkdir(parents=True, exist_ok=True)
    full = _run(d, minutes).read_bytes()
    growing = d / "growing.mcap"
    start = int(0.94 * len(full))
    growing.write_bytes(full[:start])
    car = Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml"
    # a target not reached yet: the update also works out what to drive next (as mid-run)
    cmd = [sys.executable, "-m", "stid.cli", "live", str(growing), "--follow", "--json", "--every", "0.2",
           "--no-diagnose", "--vehicle", str(car), "--model", model, "--target", "Iz=0.1%"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    updates, walls = [], []
    try:
        first = json.loads(proc.stdout.readline())  # the cold first update, on 94% of the run
        for k in range(1, steps + 1):
            end = start + (len(full) - start) * k // steps
            with open(growing, "ab") as f:  # what the logger's next flushes (and at last its close) write
                f.write(full[growing.stat().st_size:end])
            grown = time.monotonic()
            before = updates[-1] if updates else first
            while True:  # the next update that saw the new bytes (a step of the quick 1 min run is
                # under a second of data: its whole seconds may not move, the driving seconds do)
                line = proc.stdout.readline()
                if not line:
                    raise RuntimeError(f"stid live ended before the file did: {proc.stderr.read()[-2000:]}")
                doc = json.loads(line)
                if (doc["seconds"], doc["driving_s"]) > (before["seconds"], before["driving_s"]):
                    break
            walls.append(time.monotonic() - grown)
            updates.append(doc)
            if doc.get("finished"):  # the view saw the closing summary (it may come before the last bytes) and ended
                break
    finally:
        proc.kill()
        proc.wait()
    cpu = sorted(u["cpu_s"] for u in updates)
    mid = updates[[u["cpu_s"] for u in updates].index(cpu[len(cpu) // 2])]
    return {"model": model, "minutes": minutes, "samples": int(minutes * 60 * RATE_HZ), "updates": len(updates),
            "cpu_s": cpu[len(cpu) // 2], "cpu_max_s": cpu[-1], "timing": mid.get("timing", {}),
            "wall_s": sorted(walls)[len(walls) // 2], "first_cpu_s": first["cpu_s"],
            "load_avg": os.getloadavg()[0], "cores": os.cpu_count()}
