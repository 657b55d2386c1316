"""``stid export``: a logged run as CSV in the import contract (SI units)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from stid.errors import InputError
from stid.load import load_file
from stid.vehicle_file import load_vehicle


def write_csv(run, path) -> None:
    cols = {"t": run.t, "steer": run.steer, "ay": run.ay, "r": run.r, "vx": run.vx}
    if run.ax is not None:
        cols["ax"] = run.ax
    if run.beta is not None:
        cols["beta"] = run.beta
    header = ",".join(cols)
    data = np.column_stack(list(cols.values()))
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.7g")


def export_csv(run_path: str, csv_path: str, vehicle_path: str | None = None) -> int:
    vehicle = load_vehicle(vehicle_path) if vehicle_path else None
    runs = load_file(run_path, vehicle)
    if not runs:
        raise InputError(f"{run_path} holds no usable samples")
    out = Path(csv_path)
    if not out.resolve().parent.exists():
        raise InputError(f"output directory {out.resolve().parent} does not exist")
    written = []
    for k, run in enumerate(runs):
        p = out if k == 0 else out.with_name(f"{out.stem}.{k + 1}{out.suffix}")
        write_csv(run, p)
        written.append(p)
        for w in run.meta.get("warnings", []):
            print(f"warning: {run.name}: {w}", file=sys.stderr)
    note = "" if len(written) == 1 else f" (the log had {len(written)} pieces, split at unplugs or restarts)"
    print(f"wrote {', '.join(map(str, written))}{note}", file=sys.stderr)
    return 0
