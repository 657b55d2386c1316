"""`make demo`: the whole story on the simulated car.

A simulated car with hidden effects drives a manoeuvre set; its real firmware
streams over emulated serial ports; stid-log records each run; stid calibrates
the sensors, fits the bicycle model, shows where it fails, names the missing
effects, adds them, and shows the error fall, ending with the path of the report.

The demo only calls the command-line tools, as a user would. The hidden effects
are revealed at the end, from the simulator's side.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

OUT = Path("demo_out")
HIDDEN = "actuator_lag,accel_offset"
DRIVES = [  # name, stid-sim arguments
    ("standstill", ["--manoeuvre", "standstill", "--duration", "5", "--still", "0"]),
    # as on a track: the driver accelerates and brakes every 2-5 s, +-25% around 4 and 6 m/s
    ("track_4ms", ["--manoeuvre", "random_steer", "--speed", "4", "--speed-profile", "track", "--duration", "24",
                   "--seed", "1"]),
    ("track_6ms", ["--manoeuvre", "random_steer", "--speed", "6", "--speed-profile", "track", "--duration", "24",
                   "--seed", "2"]),
]


def tool(name: str) -> str:
    return str(Path(sys.executable).parent / name)


def say(text: str = "") -> None:
    print(text, flush=True)


class Ticker:
    """While a step works silently: the seconds it has taken, on one line that is
    rewritten (a terminal), or a line every 15 s (a log)."""

    def __init__(self, what: str):
        self.what = what
        self.tty = sys.stdout.isatty()
        self._stop = threading.Event()

    def __enter__(self):
        self.t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        every = 1.0 if self.tty else 15.0
        while not self._stop.wait(every):
            line = f"    ... {self.what}: {time.monotonic() - self.t0:.0f} s"
            print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", flush=True)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        if self.tty and time.monotonic() - self.t0 >= 1.0:
            print("\r" + " " * 60 + "\r", end="", flush=True)
        return False


def run(cmd, show=True) -> str:
    with Ticker(Path(cmd[0]).name + (" " + cmd[1] if len(cmd) > 1 else "")):
        proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        say(proc.stdout)
        raise SystemExit(f"demo: '{' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))}' "
                         f"failed: {proc.stderr.strip()}")
    if show and proc.stdout.strip():
        say("\n".join("    " + line for line in proc.stdout.rstrip().splitlines()))
    return proc.stdout


LIVE = "track_6ms"  # the drive watched live (stid-log --live), as a driver at the track would
LIVE_EVERY_S = 8.0  # seconds of data between the live view's updates shown here


def drive_and_log(example: Path) -> dict:
    """All drives at once, each on its own pseudo-terminal with its own stid-log; one of
    them with the live view, whose updates are shown as they come."""
    sims, loggers, files = [], {}, {}
    echo = None
    # the longest drives first: the short stand-still then ends while the others hold their
    # ports, and its logger, waiting for its port to come back, finds no other car's there
    for name, args in sorted(DRIVES, key=lambda d: -float(d[1][d[1].index("--duration") + 1])):
        sim = subprocess.Popen([tool("stid-sim"), *args, "--effects", HIDDEN], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
        port = sim.stdout.readline().split(": ", 1)[1].strip()
        path = OUT / f"{name}.mcap"
        files[name] = path
        live = ["--live", "--vehicle", str(example), "--every", "2"] if name == LIVE else []
        say(f"    {name:<11} simulated car on {port}  ->  stid-log {port} -o {path}" + " ".join([""] + live[:1]))
        loggers[name] = subprocess.Popen([tool("stid-log"), port, "-o", str(path), "--duration", "60",
                                          "--reconnect-timeout", "0.5", *live], stderr=subprocess.PIPE,
                                         stdout=subprocess.PIPE if live else None, text=True)
        if live:
            echo = LiveEcho(loggers[name].stdout)
        sims.append(sim)
    say(f"\n    the live view of {LIVE} (stid-log --live: its own process; every {LIVE_EVERY_S:.0f} s of data shown):")
    for sim in sims:
        sim.wait()
    for sim in sims:  # (their pipes: the port line was read, the rest is not needed)
        sim.stdout.close()
        sim.stderr.close()
    errs = {}
    for name, lg in loggers.items():
        if lg.stdout is not None:
            echo.thread.join(timeout=90)  # the view's last update, on the finished file
        _, err = lg.communicate()
        if lg.returncode != 0:
            raise SystemExit(f"demo: stid-log failed for {name}: {err.strip()}")
        errs[name] = err
    echo.flush()
    say("\n    each drive ended as its simulated car closed its port; stid-log waited the 0.5 s of "
        "--reconnect-timeout\n    for it to come back, then stopped (its summary says so):")
    for name, _ in DRIVES:
        say("    " + errs[name].strip().splitlines()[-1])
    return files


class LiveEcho:
    """The live view's plain lines (it is piped here), one update in LIVE_EVERY_S seconds of
    data shown, and the last one."""

    def __init__(self, stream):
        self.stream = stream
        self.block: list = []
        self.shown_at = -LIVE_EVERY_S
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        for line in self.stream:
            line = line.rstrip("\n")
            if "] stid live " in line:
                self._maybe_show(final=False)
                self.block = []
            self.block.append(line)

    def _seconds(self) -> float:
        head = self.block[0] if self.block else ""
        try:
            return float(head.split("]", 1)[0].strip("[ s"))
        except ValueError:
            return -1.0

    def _maybe_show(self, final: bool) -> None:
        if not self.block or "] stid live " not in self.block[0]:
            return
        at = self._seconds()
        if final or at >= self.shown_at + LIVE_EVERY_S:
            self.shown_at = at
            say("\n".join("      " + line for line in self.block))

    def flush(self) -> None:
        self._maybe_show(final=True)
        self.block = []


def main() -> int:
    t0 = time.time()
    if OUT.exists():
        shutil.rmtree(OUT)
    OUT.mkdir()
    vehicle = OUT / "car.toml"  # written by stid calibrate from the example's tape-and-scales values
    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "rc8.toml"
    say("stid demo: a simulated 1:8 car runs the real firmware (MicroPython) and streams over emulated\n"
        "serial ports. Something about this car is not a textbook bicycle. Let us find out what.\n")
    say("1. Drive: stand still (calibration), then random steer while speeding up and braking around\n"
        "   4 m/s and 6 m/s (+-25%, as on a track), logged in real time; the 6 m/s drive is identified\n"
        "   while it drives (precision per parameter, what the data lack, the diagnosis once it can tell)")
    files = drive_and_log(example)
    runs = [str(files["track_4ms"]), str(files["track_6ms"])]

    say("\n2. Calibrate the sensors from the stand-still run")
    with Ticker("stid calibrate"):
        proc = subprocess.run([tool("stid"), "calibrate", str(files["standstill"]), "--vehicle", str(example),
                               "-o", str(vehicle)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"demo: stid calibrate failed: {proc.stderr.strip()}")
    say("\n".join("    " + line for line in proc.stderr.strip().splitlines()))

    say("\n3. Fit the bicycle model")
    run([tool("stid"), "fit", *runs, "--vehicle", str(vehicle), "--model", "bicycle", "--method", "time"])

    say("\n4. Where does it fail, and what is missing?  (stid diagnose --peel)")
    out = run([tool("stid"), "diagnose", *runs, "--vehicle", str(vehicle), "--peel"])
    # diagnose ends with the next command; its --model is the model with what was found
    nxt = [line for line in out.splitlines() if line.startswith("next:") and "--model" in line]
    model = nxt[-1].split("--model")[-1].split()[0] if nxt else "bicycle"
    found = model.split("+")[1:]

    say(f"\n5. Add what it found: stid fit --model {model}")
    run([tool("stid"), "fit", *runs, "--vehicle", str(vehicle), "--model", model, "--method", "time"])

    say("\n6. The report: one HTML page with the chain, the overlays, the residuals and the diagnosis")
    rep = run([tool("stid"), "report", *runs, "--vehicle", str(vehicle), "-o", str(OUT / "report")], show=False)
    say(f"    {rep.strip()}")

    say(f"\nThe simulator had hidden: {HIDDEN.replace(',', ', ')}.  stid found: {', '.join(found) or 'nothing'}.")
    say(f"Done in {time.time() - t0:.0f} s. Report: {rep.strip()}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
