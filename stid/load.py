"""Load runs from stid-log MCAP files (complete or cut short) or CSV files in the
import contract (DESIGN.md), and check them for the mistakes users make."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from host.errors import HostError
from host.mcap_read import read_log
from host.mcap_scan import holds_a_log
from host import units
from stid import convert, input_checks, sensor_chain, steer_clip
from stid.errors import InputError
from stid.ros import bag as ros_bag, topic_files
from stid.run import OPTIONAL, REQUIRED, Run
from stid.vehicle_file import Vehicle, default_vehicle

# Lost frames up to this long are marked (``Run.valid``) and left out of every cost, the
# model running through them; a longer gap splits the run (the input there is unknown).
MAX_FILLED_GAP_S = 0.1
# A sample farther than this share of a period from its grid instant is "off the grid" (soft timer):
# 5% of 2 ms is 100 µs, a phase error of 0.3° at 10 Hz -- below what any fit can see.
OFF_GRID_TOLERANCE = 0.05
MIN_SAMPLES = 20

# Beyond these a value is not physical for a scale car in SI units: most likely degrees.
PLAUSIBLE = {"steer": (1.0, "rad (road-wheel angle; 1 rad is 57 deg)"),
             "r": (15.0, "rad/s"), "ay": (60.0, "m/s^2"), "vx": (60.0, "m/s"), "beta": (1.0, "rad")}


def load_runs(paths, vehicle: Vehicle | None = None) -> list[Run]:
    paths = list(paths)
    twice = same_data(paths)
    if twice:
        a, b = twice[0]
        raise InputError(f"{a} and {b} hold the same data ({'the same file' if _one_file(a, b) else 'a copy'}): a "
                         "run given twice counts twice, and its intervals come out too narrow; give each run once")
    runs, source = [], []
    for i, p in enumerate(paths):
        got = load_file(p, vehicle)
        runs.extend(got)
        source.extend([i] * len(got))
    twice = same_runs(runs, source)
    if twice:
        (a, ia), (b, ib) = twice
        pa, pb = paths[ia], paths[ib]
        raise InputError(f"{a.name} (from {pa}) and {b.name} (from {pb}) hold the same samples: a run given twice "
                         "(a bag directory named twice, a log and its export) counts twice, and its intervals come "
                         "out too narrow; give each run once")
    return runs


def same_runs(runs, source) -> tuple | None:
    """The first two runs, from different arguments (``source``: each run's), that hold the same
    samples: steer, ay and r alike to a correlation of SAME_SAMPLES (the byte-equal files
    same_data finds are refused before they are read). Not equal to the bit: a time base moved
    by 1.7e9 s (Unix time) resamples the same rows a hair apart, and a gyro zero taken from it
    moved r by 3e-5 rad/s."""
    for j in range(len(runs)):
        for i in range(j):
            if source[i] != source[j] and _same_samples(runs[i], runs[j]):
                return (runs[i], source[i]), (runs[j], source[j])
    return None


SAME_SAMPLES = 1 - 1e-9  # two drives, or one drive's two sensors' noise, are never this alike


def _same_samples(a, b) -> bool:
    n = min(len(a.steer), len(b.steer))
    if abs(len(a.steer) - len(b.steer)) > 2 or n < 3:
        return False
    for name in ("steer", "ay", "r"):
        x, y = (np.asarray(getattr(run, name), float)[:n] for run in (a, b))
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok] - x[ok].mean(), y[ok] - y[ok].mean()
        sxy, sxx, syy = float(x @ y), float(x @ x), float(y @ y)
        if sxx == 0.0 or syy == 0.0 or sxy <= 0.0 or sxy * sxy < SAME_SAMPLES * sxx * syy:
            return False
    return True


def same_data(paths, others=()) -> list[tuple]:
    """Pairs of files that hold the same bytes (one file named twice, or a copy), among
    ``paths`` or, with ``others``, between ``paths`` and ``others``. Only files of equal size
    are read."""
    import hashlib
    from functools import lru_cache

    @lru_cache(maxsize=None)
    def size(p):
        path = Path(p)
        return path.stat().st_size if path.is_file() else None  # a missing file: the loader says so

    @lru_cache(maxsize=None)
    def digest(p):
        return hashlib.sha1(Path(p).read_bytes()).digest()

    pairs = [(a, b) for i, a in enumerate(paths) for b in (others if others else paths[i + 1:])]
    return [(a, b) for a, b in pairs
            if size(a) is not None and size(a) == size(b) and (_one_file(a, b) or digest(a) == digest(b))]


def _one_file(a, b) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve() or Path(a).samefile(b)
    except OSError:
        return False


def load_file(path, vehicle: Vehicle | None = None) -> list[Run]:
    runs = _load_file(path, vehicle)
    for run in runs:
        clip = steer_clip.clip_warning(run, vehicle.L if vehicle is not None else None)
        if clip:
            run.warn(clip)
    return runs


def _load_file(path, vehicle: Vehicle | None = None) -> list[Run]:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path} does not exist")
    topic_csvs = path.is_dir() and vehicle is not None and topic_files.names_files(vehicle.ros)
    if ros_bag.kind_of(path) or topic_csvs:  # told by content: a ROS 2 MCAP shares its magic with a stid-log one
        from stid.ros.to_run import load_bag

        return load_bag(path, vehicle)
    if path.is_dir():
        raise InputError(f"{path} is a directory (and not a ROS 2 bag: no metadata.yaml); give the run files "
                         "(RUN.mcap, RUN.bag or RUN.csv), or for one CSV per topic name them in the vehicle file's "
                         "[ros] (docs/ros.md)")
    if path.stat().st_size == 0:
        raise InputError(f"{path} is empty")
    if holds_a_log(path):
        return load_mcap(path, vehicle)
    if path.suffix.lower() == ".mcap":
        raise InputError(f"{path} is named .mcap but is not an MCAP file (no MCAP magic at its start): "
                         "corrupted, or not written by stid-log")
    if path.suffix.lower() in (".bag", ".db3"):
        raise InputError(f"{path} is named {path.suffix} but is not a ROS bag (a ROS 1 bag starts with "
                         "'#ROSBAG V2.0', a ROS 2 .db3 is an SQLite file beside its metadata.yaml): corrupted, "
                         "cut short, or not a bag (docs/ros.md)")
    if path.suffix.lower() == ".toml":  # the mirror of a run given as --vehicle
        raise InputError(f"{path} is a vehicle file, not a run: give the runs (RUN.mcap or RUN.csv) first and "
                         "the vehicle file after --vehicle")
    runs = _cut_at_unknown_input(load_csv(path, vehicle))
    for run in runs:
        run.meta["sensor_chain"] = sensor_chain.from_vehicle(vehicle)
    return runs


# -- CSV ------------------------------------------------------------------------

def load_csv(path, vehicle: Vehicle | None = None) -> Run:
    """A CSV run: the import contract's columns, or the vehicle file's ``[csv]`` map of them
    (stid.csv_map); a steering column in servo units through its ``[steering]`` map."""
    import pandas as pd

    from stid import csv_map

    path = Path(path)
    df, sep, decimal = csv_map.read(path, "neither an MCAP file nor a readable CSV")
    table = vehicle.csv if vehicle is not None else {}
    df = csv_map.apply(df, table, str(path))
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        read_as = "" if sep == "," else f" (read as {csv_map.describe(sep, decimal)})"
        raise InputError(f"{path} lacks the column(s) {', '.join(missing)}; its columns{read_as}: "
                         f"{', '.join(df.columns[:12])}{' ...' if len(df.columns) > 12 else ''}. The CSV contract needs "
                         f"{', '.join(REQUIRED)} (SI units: s, rad, m/s^2, rad/s, m/s); map yours with a [csv] table "
                         "in the vehicle file, e.g. ay = \"-imu_ax\" (docs/ros.md)")
    if len(df) < MIN_SAMPLES:
        raise InputError(f"{path} has only {len(df)} rows; a run needs at least {MIN_SAMPLES} samples")
    cols, unknown, notes = _numeric_columns(df, path)
    from stid.steer_units import road_wheel_angle

    fs = 1.0 / float(np.median(np.diff(cols["t"]))) if np.all(np.diff(cols["t"]) > 0) else 100.0
    cols["steer"], steer_notes, steer_warnings = road_wheel_angle(cols["steer"], cols["r"], cols["vx"], cols["ay"],
                                                                  fs, vehicle, str(path))
    _check_units(path, cols)
    t = cols.pop("t")
    warnings = list(steer_warnings)
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        where = f"at data row {k + 2} (line {k + 3} of the file, after its header)"
        if dt[k] == 0:
            raise InputError(f"{path}: time 't' repeats {where}: a row written twice? remove the duplicates")
        med = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        if med > 0 and -dt[k] > 10 * med:  # (sorting would interleave two runs)
            raise InputError(f"{path}: time 't' goes back {-dt[k]:.3g} s {where}: a clock reset, or two logs joined? "
                             "split the file there into two runs")
        raise InputError(f"{path}: time 't' goes back {where}: rows out of order? sort them by 't'")
    input_checks.check_time_steps(str(path), t)
    med = float(np.median(dt))
    valid = ~unknown["rows"] if unknown["rows"].any() else None
    notes = list(steer_notes) + notes
    if sep != "," or table:
        notes.append(f"read as {csv_map.describe(sep, decimal)}"
                     + (f", columns mapped by the vehicle file's [csv] ({', '.join(table)})" if table else ""))
    input_unknown = unknown["input"]
    if np.max(np.abs(dt - med)) > 0.05 * med:
        tu = t[0] + med * np.arange(int(round((t[-1] - t[0]) / med)) + 1)
        for k in cols:
            cols[k] = np.interp(tu, t, cols[k])
        pos = (t - t[0]) / med
        on_grid = np.abs(pos - np.round(pos)) < 0.05
        if on_grid.all():
            # rows missing from a uniform log (lost samples): hold the grid's place, never data
            place = np.round(pos).astype(np.int64)
            missing = len(tu) - len(t)
            valid = np.zeros(len(tu), bool)
            valid[place] = ~unknown["rows"]
            input_unknown = np.ones(len(tu), bool)
            input_unknown[place] = unknown["input"]
            notes.append(f"{missing} missing rows ({100 * missing / len(tu):.1f}%: time steps up to "
                         f"{dt.max() * 1e3:.1f} ms in a {med * 1e3:.2f} ms log) are left out of every fit")
        else:
            warnings.append(f"time was irregular (steps {dt.min() * 1e3:.2f}-{dt.max() * 1e3:.2f} ms): "
                            f"resampled to {1 / med:.1f} Hz by linear interpolation")
            # a grid sample next to a row that was not measured is not one either
            valid = None if valid is None else np.interp(tu, t, (~valid).astype(float)) == 0.0
            input_unknown = np.interp(tu, t, unknown["input"].astype(float)) > 0.0
        t = tu
    extra = {c: pd.to_numeric(df[c], errors="coerce").to_numpy(float)[unknown["timed"]] for c in df.columns
             if c not in REQUIRED and c not in OPTIONAL}
    if len(t) != int(unknown["timed"].sum()):  # extra columns stay on the rows' own times: not carried onto a new grid
        extra = {}
    run = Run(name=path.name, t=t - t[0], steer=cols["steer"], ay=cols["ay"], r=cols["r"], vx=cols["vx"],
              ax=cols.get("ax"), beta=cols.get("beta"),
              extra={**{k: v for k, v in cols.items() if k in OPTIONAL and k not in ("ax", "beta")}, **extra},
              meta={"source": str(path), "format": "csv", "notes": notes}, valid=valid)
    if input_unknown.any():
        run.meta["input_unknown"] = input_unknown  # where load_file cuts the run (_cut_at_unknown_input)
    for w in warnings:
        run.warn(w)
    _csv_gyro_zero(run)
    input_checks.check_kinematics(run, source="csv")
    return run


# A required column may lack values in some rows (a logger that writes an empty field, NaN or
# "n/a" where a sensor missed its sample): those rows are not measurements, as rows lost from a
# uniform log are not. More than this share missing is not a logger's gap but a wrong column.
MAX_MISSING_SHARE = 0.5
# The speed's missing values in gaps up to this long are filled from its neighbours, and their rows
# stay measurements: a wheel speed or odometry logged at 50 Hz in a 200 Hz file (three rows in four
# without it) is a slower channel, not lost samples, and the speed barely changes within a gap this
# short (a ROS bag's odometry is interpolated onto the IMU's instants alike, stid.ros.to_run).
SPEED_FILL_S = MAX_FILLED_GAP_S  # (a longer gap cuts the run: _cut_at_unknown_input)


def _numeric_columns(df, path):
    """The contract's columns as numbers: ``(columns, unknown, notes)``. A value that is missing or
    not a number marks its row not measured (``unknown["rows"]``; ``unknown["input"]`` where it is
    the model's input, steer or vx) and holds a place filled from its neighbours; rows without a
    time are dropped (their place, if the log is uniform, is then a missing row's). A column
    missing in most rows is refused: most likely the wrong column."""
    import pandas as pd

    notes = []
    present = list(REQUIRED) + [c for c in OPTIONAL if c in df.columns]
    raw = {c: pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=float) for c in present}
    bad = {c: ~np.isfinite(x) for c, x in raw.items()}
    n = len(df)
    filled = _fill_speed(raw, bad)
    if filled:
        notes.append(filled)
    for c in list(present):
        share = float(bad[c].mean())
        if c not in REQUIRED and share == 1.0:
            notes.append(f"column '{c}' holds no numbers: left out")
            present.remove(c)
            continue
        if share > MAX_MISSING_SHARE:
            first = int(np.flatnonzero(bad[c])[0])
            raise InputError(f"{path}: column '{c}' has {int(bad[c].sum())} missing or non-numeric values in "
                             f"{n} rows (first at data row {first + 1}: {_cell(df[c].iloc[first])}): more than half, "
                             "so not a logger's gaps; is it the right column (the vehicle file's [csv] map), "
                             "and the delimiter and decimal mark the file uses?")
    timed = ~bad["t"]
    if timed.sum() < MIN_SAMPLES:
        raise InputError(f"{path} has only {int(timed.sum())} rows with a time; a run needs at least {MIN_SAMPLES} "
                         "samples")
    cols = {c: raw[c][timed] for c in present}
    rows = np.zeros(int(timed.sum()), bool)
    inputs = np.zeros(len(rows), bool)
    counts = {}
    t = cols["t"]
    for c in present[1:]:
        b = bad[c][timed]
        if b.any():
            counts[c] = int(b.sum())
            rows |= b
            if c in ("steer", "vx"):
                inputs |= b
            cols[c] = np.where(b, np.interp(t, t[~b], cols[c][~b]), cols[c]) if (~b).any() else np.zeros(len(t))
    if not timed.all():
        first = int(np.flatnonzero(~timed)[0])
        notes.append(f"{int((~timed).sum())} row(s) without a number in 't' (first at data row {first + 1}) dropped")
    if rows.any():
        first = int(np.flatnonzero(rows)[0])
        notes.append(f"{int(rows.sum())} row(s) ({100 * rows.mean():.1f}%) lack a value or hold one that is not a "
                     f"number ({', '.join(f'{c} {k}' for c, k in counts.items())}; first at time {t[first]:g} s): "
                     "not measurements, left out of every fit as lost samples are")
    return cols, {"rows": rows, "input": inputs, "timed": timed}, notes


def _cell(value) -> str:
    """A CSV cell as the user wrote it (pandas reads an empty one as a float nan)."""
    if isinstance(value, float) and np.isnan(value):
        return "empty or nan"
    return repr(str(value))


def _fill_speed(raw: dict, bad: dict) -> str:
    """The speed's values missing in gaps up to SPEED_FILL_S (by the file's own times) filled in
    linearly from the values around them, in ``raw`` and ``bad``; what was done, in words (empty:
    nothing)."""
    raw["vx"] = vx = raw["vx"].copy()  # (pandas may hand a read-only view)
    t, gaps = raw["t"], bad["vx"] & ~bad["t"]
    have = ~bad["vx"] & ~bad["t"]
    if not gaps.any() or have.sum() < 2:
        return ""
    idx = np.flatnonzero(have)
    after = np.searchsorted(idx, np.flatnonzero(gaps))  # the first value after each missing one
    inside = (after > 0) & (after < len(idx))
    rows = np.flatnonzero(gaps)[inside]
    span = t[idx[after[inside]]] - t[idx[after[inside] - 1]]
    rows = rows[span <= SPEED_FILL_S + 1e-9]
    if not len(rows):
        return ""
    vx[rows] = np.interp(t[rows], t[idx], vx[idx])
    bad["vx"][rows] = False
    rate = len(idx) / max(float(t[idx[-1]] - t[idx[0]]), 1e-9)
    return (f"vx is missing in {len(rows)} row(s) ({100 * len(rows) / len(t):.0f}%) between values at most "
            f"{1e3 * SPEED_FILL_S:.0f} ms apart (a speed logged at ~{rate:.0f} Hz?): filled in linearly, the rows "
            "kept (the speed barely changes in that time)")


def _cut_at_unknown_input(run) -> list:
    """The run in pieces where its input (steer or vx) is unknown for longer than
    MAX_FILLED_GAP_S: the model would run through such a gap on made-up input, and its states
    after it would be wrong while they settle (a stid-log file is cut at such a gap too).
    Shorter ones stay in, not measured (``Run.valid``). Each piece keeps the run's gyro zero."""
    unknown = run.meta.pop("input_unknown", None)
    if unknown is None:
        return [run]
    long = int(np.ceil(MAX_FILLED_GAP_S * run.fs))
    spans = [(a, b) for a, b in _true_spans(unknown) if b - a > long]
    if not spans:
        return [run]
    cuts = [0] + [i for span in spans for i in span] + [len(run.t)]
    kept = [(a, b) for a, b in zip(cuts[::2], cuts[1::2]) if b - a >= MIN_SAMPLES]
    pieces = [run.slice(a, b, run.name if k == 0 else f"{run.name}#{k + 1}") for k, (a, b) in enumerate(kept)]
    gap_s = sum(b - a for a, b in spans) / run.fs
    words = (f"steer or vx unknown for {gap_s:.1f} s in {len(spans)} gap(s) longer than "
             f"{1e3 * MAX_FILLED_GAP_S:.0f} ms: the run is cut there")
    if not pieces:
        raise InputError(f"{run.meta['source']}: {words}, and no piece of {MIN_SAMPLES} samples is left")
    for p in pieces:
        p.meta = dict(p.meta, notes=list(p.meta.get("notes", [])))
        if p.valid is not None and p.valid.all():
            p.valid = None
    pieces[0].meta["notes"].append(words + (f" ({piece_names([p.name for p in pieces])})" if len(pieces) > 1
                                            else ""))
    return pieces


def _true_spans(mask: np.ndarray) -> list:
    """(start, end) of each run of True in a boolean array."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def _csv_gyro_zero(run) -> None:
    """The CSV contract has r in rad/s, not zeroed, and a gyro's zero drifts from run to run
    (HARDWARE.md: estimate it from every run's stand-still): a CSV's stand-still sets it, as an
    MCAP's and a ROS bag's do. Taking the still mean off an r that was zeroed already (stid
    export) moves it by that mean, the noise's average. Said in a note either way."""
    zero = convert.zero_from_stand_still(run)
    bias = run.meta["gyro_bias"]
    notes = run.meta.setdefault("notes", [])
    if bias is None:
        notes.append("r taken as logged: the run stands still for under 0.5 s, not counting the last "
                     f"{convert.START_LOOKBACK_S:g} s before it drives off (a wheel sensor may not see the start), "
                     "too little to show the gyro's zero")
        return
    still_s = zero["still_s"]
    run.r = run.r - bias
    # (the seconds used and the zero's own error said where a driver reads them: a trial user's 3 s stand-still
    # gave 1.8 s, and asked why; the error is what the floor's comparison in r allows for)
    notes.append(f"gyro zero {bias:+.4f} rad/s ({np.degrees(bias):+.2f} deg/s) +- {np.degrees(zero['stderr']):.2f} "
                 f"deg/s, the mean of r over {still_s:.1f} s standing still (not counting the last "
                 f"{convert.START_LOOKBACK_S:g} s before it drives off, which a wheel sensor may not see), taken off r")


def _check_units(path, cols):
    for name, (limit, unit) in PLAUSIBLE.items():
        if name in cols:
            peak = float(np.max(np.abs(cols[name])))
            if peak > limit:
                hint = " — that looks like degrees; convert to radians" if name in ("steer", "r", "beta") else ""
                raise InputError(f"{path}: '{name}' reaches {peak:.3g}, implausible in {unit}{hint}")


# -- MCAP -----------------------------------------------------------------------

def load_mcap(path, vehicle: Vehicle | None = None, log=None) -> list[Run]:
    """The runs of a stid-log file; ``log``: its ``read_log`` when the caller has read it
    already (stid live reads the events and statistics too)."""
    vehicle = vehicle or default_vehicle()
    try:
        log = log if log is not None else read_log(path)
    except HostError as e:
        raise InputError(str(e)) from None
    s = log.samples
    if len(s) < MIN_SAMPLES:
        if log.truncated:  # the head of a file that was cut (a copy stopped, a logger killed early)
            raise InputError(f"{path} was cut short after {Path(path).stat().st_size} bytes and holds {len(s)} "
                             "samples before the cut: too few to use (a copy that stopped, or a logger "
                             "killed at once): copy the whole file again, or record the run again")
        raise InputError(f"{path} holds {len(s)} samples: too few to use (was the logger connected to the car?)")
    if not log.hello:
        raise InputError(f"{path} has samples but no HELLO frame got through, so the ADC scale is unknown; "
                         f"supply one from an earlier log of the same board: 'stid repair {path} "
                         "--hello-from EARLIER.mcap'")
    runs = []
    for k, (a, b) in enumerate(_pieces(s)):
        piece = s[a:b]
        if len(piece) < MIN_SAMPLES:
            continue
        name = Path(path).name if k == 0 else f"{Path(path).name}#{k + 1}"
        runs.append(_convert(piece, log, vehicle, name, str(path)))
        runs[-1].meta["segment"] = int(piece["segment"][0]) if "segment" in (piece.dtype.names or ()) else 0
    _share_gyro_bias(runs)
    _link_losses(runs)
    # (whoever prints a run's warnings names the run: they do not repeat the file's name)
    if log.truncated:
        for r in runs:
            r.warn("the file was cut short (logger killed?): read up to its last complete chunk; "
                   "'stid repair' makes it a complete file")
    damage = log.damage_note()
    if damage:
        for r in runs:
            r.warn(damage)
    supplied = log.hello.get("supplied_from")
    if supplied:
        for r in runs:
            r.warn(f"no HELLO was received in this log; its configuration was supplied from {supplied}")
    for r in runs:
        input_checks.check_kinematics(r, source="mcap")
    return runs


def _link_losses(runs) -> None:
    """The samples a log lost on the link, said once, on its first piece: a lossy link cuts a
    log into pieces, and each piece saying its own share made a note line per piece."""
    n_lost = sum(r.meta.get("link_lost", 0) for r in runs)
    if not n_lost:
        return
    n = sum(len(r.t) for r in runs)
    cut = (f"; the log is in {len(runs)} pieces, cut where samples were lost or the car restarted "
           f"({piece_names([r.name for r in runs])})") if len(runs) > 1 else ""
    runs[0].meta.setdefault("notes", []).append(
        f"{n_lost} samples lost on the link ({100 * n_lost / n:.1f}%), left out of every fit{cut}")


def piece_names(names: list) -> str:
    """drop.mcap#3, #4, #5: the pieces of one log, its name said once."""
    return ", ".join([names[0]] + [f"#{n.rsplit('#', 1)[1]}" if "#" in n else n for n in names[1:]])


def _share_gyro_bias(runs) -> None:
    """A piece cut off by a gap (a burst of lost frames) has no stand-still of its own; the
    gyro's zero from the still part of another piece since the same boot holds for it."""
    for r in runs:
        if r.meta.get("gyro_bias") is not None:
            continue
        donors = [d for d in runs if d.meta.get("gyro_bias") is not None
                  and d.meta.get("segment") == r.meta.get("segment")]
        if donors:
            bias = donors[0].meta["gyro_bias"]
            r.r = r.r - bias
            convert.set_gyro_zero(r, donors[0].meta.get("gyro_zero"),
                                  f"the stand-still of {donors[0].name} (same boot)")
            r.meta["calibration"]["gyro_bias_rad_s"] = bias
            r.meta.setdefault("notes", []).append(
                f"gyro zero taken from the stand-still of {donors[0].name} (same boot)")
        else:
            r.warn("the run never stands still: gyro bias not re-estimated (start runs with ~3 s standing still)")


def _pieces(s):
    """Split where the firmware restarted or the stream stopped for longer than
    MAX_FILLED_GAP_S (an unplug). Samples with one time stamp but successive indices are
    a soft timer's queued callbacks run in one burst after a blocking write (ESP32): one
    piece, not a restart (each such burst used to cut an ESP32 run into 10 s pieces)."""
    t = s["t_mcu_us"].astype(np.int64)
    if len(t) < 2:
        return [(0, len(t))]
    dt = np.diff(t)
    stalled = dt == 0
    if "index" in (s.dtype.names or ()):
        step = (np.diff(s["index"].astype(np.int64)) % (1 << 30))
        # a burst: the index goes on by a period or a few (missed ones); a restart starts it
        # again from 0, i.e. a step of nearly 2^30
        stalled &= ~((step >= 1) & (step <= 64))
    brk = (np.diff(s["segment"]) != 0) | (dt > MAX_FILLED_GAP_S * 1e6) | (dt < 0) | stalled
    cuts = np.concatenate([[0], np.flatnonzero(brk) + 1, [len(t)]])
    return list(zip(cuts[:-1], cuts[1:]))


def _filled(v: np.ndarray, t) -> np.ndarray:
    """``v`` with its NaNs interpolated from the known values around them (held at the ends;
    zeros when nothing is known): a place holder for rows marked not measured."""
    bad = np.isnan(v)
    if not bad.any():
        return v
    if bad.all():
        return np.zeros(len(v))
    return np.where(bad, np.interp(t, t[~bad], v[~bad]), v)


def _convert(s, log, vehicle: Vehicle, name: str, source: str) -> Run:
    hello = log.hello
    t_us = s["t_mcu_us"].astype(np.int64)
    # The sample grid comes from the firmware's sample index (it advances every timer period,
    # sampled or missed): a soft timer's late samples and the car's missed periods then land
    # where they belong, and the grid never runs short of the samples it holds.
    k = (s["index"].astype(np.int64) - int(s["index"][0])) % int(hello.get("mod", 1 << 30))
    one = np.diff(k) == 1
    step = float(np.median(np.diff(t_us)[one])) if one.any() else float(np.median(np.diff(t_us) / np.diff(k)))
    t0 = float(np.median(t_us - k * step))  # robust to late samples: most are on time
    tu = t0 + np.arange(int(k[-1]) + 1) * step
    nearest = k
    # (distinct places counted by a sort: numpy 2.4's hashing np.unique took 0.17 s of 150k samples)
    filled = len(tu) - (np.count_nonzero(np.diff(np.sort(k))) + 1)
    ax, ay, az = convert.accelerations(s, hello, vehicle)
    r = convert.yaw_rate(s, hello, vehicle)
    steer = convert.steer_angle(s["steer_us"], vehicle)
    ppr = int(hello.get("wheel", {}).get("pulses_per_rev", vehicle.pulses_per_rev))
    vx = units.wheel_speed(t_us, s["t_us"], s["wheel_count"], s["wheel_t_us"], ppr, vehicle.wheel_radius,
                           int(hello.get("mod", 1 << 30)), centred=True)
    no_pulse = np.isnan(steer)
    sig = {"steer": steer, "ay": ay, "r": r, "vx": vx}
    for k, v in (("ax", ax), ("az", az)):
        if not np.all(np.isnan(v)):  # (a channel the board does not sample is absent, not unknown)
            sig[k] = v
    wheels = {k: w for k, w in units.wheel_speeds(t_us, s, hello, int(hello.get("mod", 1 << 30)),
                                                   centred=True).items()
              if k in OPTIONAL and not np.all(np.isnan(w))}
    if len(wheels) == 4:  # the four wheel speeds study 2's grey-box needs [rad/s]
        sig.update(wheels)
        # the rear axle is driven and slips; the free-rolling fronts measure the car's speed
        sig["vx"] = 0.5 * (wheels["w_fl"] + wheels["w_fr"]) * vehicle.wheel_radius
    # A value the samples cannot tell (the speed before the first hall interval of a piece, the
    # steer before the first pulse or with the receiver off, a channel lost in a record) is
    # unknown: its row is not a measurement (valid False), left out of every fit and export,
    # and only holds the grid's place with a value interpolated from its known neighbours.
    unknown = np.zeros(len(t_us), bool)
    for v in sig.values():
        unknown |= np.isnan(v)
    sig = {k: _filled(v, t_us) for k, v in sig.items()}
    valid = None
    # A hard timer samples within µs of its grid instant; a soft timer (ESP32) runs late, by
    # milliseconds behind a blocking write. A value is where its t_us says, never where the grid is.
    off_grid = np.abs(t_us - tu[nearest]).max() > OFF_GRID_TOLERANCE * step
    if filled or off_grid:
        # the grid needs a value at every place: interpolated from the samples' true instants;
        # a grid place no sample is near (a gap) is held and marked not measured
        sig = {k: np.interp(tu, t_us, v) for k, v in sig.items()}
        valid = np.zeros(len(tu), bool)
        valid[nearest[~unknown]] = True
    elif unknown.any():
        valid = ~unknown
    timed = False
    if "steer_t_us" in (s.dtype.names or ()):
        exact, timed = convert.steer_at_servo_times(t_us, s["t_us"], s["steer_us"], s["steer_t_us"], vehicle,
                                                    int(hello.get("mod", 1 << 30)), tu, step)
        if timed:
            no_exact = np.isnan(exact)
            if no_exact.any():
                valid = ~no_exact if valid is None else valid & ~no_exact
            sig["steer"] = _filled(exact, tu)
            fall, width = convert.logged_pulses(t_us, s["t_us"], s["steer_us"], s["steer_t_us"],
                                                int(hello.get("mod", 1 << 30)))
            few = fast_receiver_warning(fall - width, 1e6 / step)
    t = (tu - tu[0]) * 1e-6
    fs = 1e6 / step
    run = Run(name=name, t=t, steer=sig["steer"], ay=sig["ay"], r=sig["r"], vx=sig["vx"], ax=sig.get("ax"),
              extra={k: v for k, v in sig.items() if k == "az" or k.startswith("w_")},
              meta={"source": source, "format": "mcap", "hello": hello, "fs": fs, "t0_mcu_s": tu[0] * 1e-6,
                    "sensor_chain": sensor_chain.from_hello(hello, vehicle)},
              valid=valid)
    run.meta["steer_timing"] = "servo pulse edges" if timed else "sample instants"
    for late_edges in (scheduled_steer_note(hello), scheduled_hall_note(hello)):
        if late_edges:
            run.meta.setdefault("notes", []).append(late_edges)
    if not timed:
        run.meta.setdefault("notes", []).append(
            "steer timed at the sample instants (this log does not carry the servo pulses' edge times, "
            "protocol v1): each steering step sits up to one sample period late")
    if off_grid:
        late = np.abs(t_us - tu[nearest])
        run.meta.setdefault("notes", []).append(
            f"samples off their nominal instants by up to {late.max() / 1e3:.1f} ms (soft timer?): "
            "values interpolated to the sample grid from their measured times")
    if filled:
        run.meta["link_lost"] = int(filled)  # (said once for the whole log: _link_losses)
    if timed and few:
        run.warn(few)
    if no_pulse.mean() > 0.01:
        run.warn(f"no steering pulse in {100 * no_pulse.mean():.0f}% of samples (receiver off?): the steer is "
                 "unknown there, and those samples are left out")
    clip = units.clipped(s["ay"], hello) | units.clipped(s["ax"], hello)
    if clip.any():
        run.warn(f"{int(clip.sum())} accelerometer samples at the ADC limit (clipped)")
        run.extra["clipped"] = clip.astype(float) if valid is None else np.interp(tu, t_us, clip.astype(float))
    convert.zero_from_stand_still(run, fs)
    bias = run.meta["gyro_bias"]
    if bias is not None:
        run.r = run.r - bias
    run.meta["calibration"] = {"steer_center_us": vehicle.steer_center_us,
                               "steer_us_per_rad": vehicle.steer_us_per_rad,
                               "wheel_radius": vehicle.wheel_radius, "sensors": vehicle.sensors,
                               "gyro_bias_rad_s": bias}
    return run


def scheduled_hall_note(hello: dict) -> str | None:
    """A note for a log whose hall edges an ESP32 counted and timed with pin callbacks (scheduled
    there, as the steering's were): firmware 0.3.3 times one hall sensor with the pulse counter
    (HELLO capture.hall "pcnt"); four sensors need more units than the ESP32 has."""
    if hello.get("board") != "esp32" or (hello.get("capture") or {}).get("hall", "irq") != "irq":
        return None
    return ("hall edges timed by scheduled pin callbacks (ESP32): in a simulation of the port, edges late by up "
            "to a frame write on 9% of the samples at 500 Hz and the wheel speed off by more than 1% on 11%; "
            "firmware 0.3.3 with one hall sensor times them with the pulse counter (HELLO capture.hall 'pcnt') "
            "to ±1 µs")


PULSES_LOGGED_MIN = 0.9  # below this share of the receiver's pulses in the records, say so


def fast_receiver_warning(rise_us: np.ndarray, fs: float) -> str | None:
    """A warning when the records carry only part of the receiver's pulses: a record holds the
    latest pulse at its instant, so a receiver that sends frames faster than the firmware
    samples (surface receivers: 91-333 Hz) has pulses no record holds. Their commands are
    interpolated between the recorded ones (convert._fill_lost_pulses); a step between two
    records is placed where the interpolation puts it, not where it was."""
    period = convert.receiver_period_us(rise_us)
    share = convert.pulses_in_log(rise_us, period)
    if share is None or share >= PULSES_LOGGED_MIN:
        return None
    rx_hz = 1e6 / period
    return (f"the receiver sent a servo pulse every {period / 1e3:.1f} ms ({rx_hz:.0f} Hz) and the firmware "
            f"sampled at {fs:.0f} Hz: each sample records only the latest pulse, so {100 * share:.0f}% of them are "
            f"in this log; the others' commands are interpolated between them. Log at {_rate_above(rx_hz)} Hz or "
            "more (stid flash --rate) to record every pulse")


def _rate_above(hz: float) -> int:
    # the lowest rate that divides 10^6 (the firmware's grid is whole us) at or above hz
    return next(r for r in (100, 125, 200, 250, 400, 500, 625, 1000, 2000, 2500, 5000) if r >= hz)


def scheduled_steer_note(hello: dict) -> str | None:
    """A note for a log whose steering pulses an ESP32 timed with pin callbacks: those are
    scheduled there (ports/esp32/machine_pin.c), so an edge is timed when its callback
    runs, after any UART write, and is lost when the scheduler queue is full. Firmware
    0.3.2 times them with the pulse counter (HELLO capture.servo "pcnt")."""
    if hello.get("board") != "esp32" or (hello.get("capture") or {}).get("servo", "irq") != "irq":
        return None
    return ("steering pulses timed by scheduled pin callbacks (ESP32 without the pulse counter): in a "
            "simulation of the port 5% of the pulses were missed and 7% had widths off by more than "
            "100 µs, their edges late by up to a frame write; flash firmware 0.3.2 or later (HELLO "
            "capture.servo 'pcnt') for widths and edges to ±1 µs")
