"""``stid export``: a logged run as CSV in the import contract (SI units)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from stid.errors import InputError
from stid.load import load_file
from stid.output_paths import refuse_existing
from stid.sensor_chain import describe
from stid.vehicle_file import load_vehicle


def write_csv(run, path) -> None:
    """The run's measured samples; samples lost on the link are left out (their rows are
    missing, so the time column shows the gap: an importer sees a gap, never a guess)."""
    cols = {"t": run.t, "steer": run.steer, "ay": run.ay, "r": run.r, "vx": run.vx}
    if run.ax is not None:
        cols["ax"] = run.ax
    if run.beta is not None:
        cols["beta"] = run.beta
    for k in ("w_fl", "w_fr", "w_rl", "w_rr"):
        if k in run.extra:
            cols[k] = run.extra[k]
    header = ",".join(cols)
    data = np.column_stack(list(cols.values()))
    if run.valid is not None:
        data = data[np.asarray(run.valid, bool)]
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.7g")


def export_csv(run_path: str, csv_path: str, vehicle_path: str | None = None, overwrite: bool = False) -> int:
    """``csv_path`` "-": the CSV on stdout (a log in one piece)."""
    if csv_path == "-":
        return _export_to_stdout(run_path, vehicle_path)
    out = Path(csv_path)
    if not out.resolve().parent.exists():
        raise InputError(f"output directory {out.resolve().parent} does not exist")
    from host.mcap_scan import holds_a_log

    if holds_a_log(out):
        raise InputError(f"--csv {out} is a recorded run (an MCAP file): export never replaces one; give the CSV "
                         "another name")
    if out.exists() and Path(run_path).exists() and out.resolve() == Path(run_path).resolve():
        # (--overwrite turned a trial user's 1.1 MB logged CSV into its first 2.6 s: the input is a
        # recorded run, whatever its format)
        raise InputError(f"--csv {out} is the run being exported: export never writes over its input, even with "
                         "--overwrite; give the CSV another name")
    refuse_existing([out], "stid export", overwrite)  # before the loading: known at once
    vehicle = load_vehicle(vehicle_path) if vehicle_path else None
    runs = load_file(run_path, vehicle)
    if not runs:
        raise InputError(f"{run_path} holds no usable samples")
    # a log cut into pieces writes OUT.2.csv, OUT.3.csv, ... beside OUT.csv
    paths = [out if k == 0 else out.with_name(f"{out.stem}.{k + 1}{out.suffix}") for k in range(len(runs))]
    if any(p.exists() and p.resolve() == Path(run_path).resolve() for p in paths):
        raise InputError(f"--csv {out}: a piece's name ({', '.join(map(str, paths[1:]))}) is the run being "
                         "exported: give the CSV another name")
    refuse_existing(paths[1:], "stid export", overwrite)
    written = []
    for run, p in zip(runs, paths):
        write_csv(run, p)
        written.append(p)
        for w in run.meta.get("warnings", []):
            print(f"warning: {run.name}: {w}", file=sys.stderr)
    _note_the_sensor_chain(runs[0])
    note = "" if len(written) == 1 else (f" (the log had {len(written)} pieces, split where the stream "
                                         "stopped or its steer or speed was unknown for more than 0.1 s: an "
                                         "unplug, a restart, a burst of lost frames or rows without values; "
                                         "each piece's t starts at 0)")
    print(f"wrote {', '.join(map(str, written))}{note}", file=sys.stderr)
    return 0


def _export_to_stdout(run_path: str, vehicle_path: str | None) -> int:
    vehicle = load_vehicle(vehicle_path) if vehicle_path else None
    runs = load_file(run_path, vehicle)
    if not runs:
        raise InputError(f"{run_path} holds no usable samples")
    if len(runs) > 1:
        raise InputError(f"{run_path} is a log of {len(runs)} pieces (split where the stream stopped, or its steer "
                         "or speed was unknown, for more than 0.1 s), a CSV each: give --csv a file name (OUT.csv, "
                         "OUT.2.csv, ... are written)")
    write_csv(runs[0], sys.stdout)
    for w in runs[0].meta.get("warnings", []):
        print(f"warning: {runs[0].name}: {w}", file=sys.stderr)
    _note_the_sensor_chain(runs[0])
    return 0


def _note_the_sensor_chain(run) -> None:
    chain = run.meta.get("sensor_chain")
    if chain and (chain.get("ay") or chain.get("r")):
        keys = {"ay": "accel_bandwidth_hz", "r": "gyro_bandwidth_hz"}
        decl = ", ".join(f"{keys[o]} = {chain[o]:g}" for o in ("ay", "r") if chain.get(o))
        print(f"note: the CSV holds the sensors' outputs ({describe(chain)}); a CSV carries no sensor "
              f"chain, so declare it when fitting the CSV: [sensors] {decl} in the vehicle file",
              file=sys.stderr)
