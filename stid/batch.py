"""``stid batch``: fit (and optionally diagnose) many runs: a season of logs, a Monte
Carlo study. Each run is an independent job on local processes, or on an existing
Dask distributed cluster (``--scheduler tcp://host:8786``, extra ``stid[dask]``).
Results go into one table (CSV or Parquet) plus summary plots of parameter drift.

A run that fails (a bad file) becomes a row with its error, not the end of the batch.
"""

from __future__ import annotations

import glob
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from stid.errors import InputError, StidError
from stid.output_paths import refuse_existing, unwritable


def find_runs(pattern, skipped: list | None = None) -> list[str]:
    """The runs named by ``pattern``: a directory (its runs), a glob (the runs it matches), a file
    (itself, whatever it holds: a file named is tried, and fails as a row if it is no run), or a
    list of them (several arguments, or the files a shell expanded an unquoted glob into), each
    run once, in the order their names count: run_2 before run_10 (sorted as text, a trial's
    session 10 was drawn before sessions 1 and 2 on the drift plot). ``skipped``: told what was
    passed over (a directory's subdirectories and files that are no runs). Only the first of several
    arguments was read before: a trial user's second directory of 13 runs was dropped, exit 0."""
    patterns = [pattern] if isinstance(pattern, str) else list(pattern)
    skipped = [] if skipped is None else skipped
    files: dict[str, None] = {}
    for pat in patterns:
        if glob.has_magic(pat):
            matches = sorted(glob.glob(pat), key=_counted)
            if not matches:
                raise InputError(f"nothing matches {pat!r}: give a directory of runs, the runs, or a glob like "
                                 "'logs/*.mcap'")
            for m in matches:
                _add(Path(m), files, skipped, named=False)
        elif not Path(pat).exists():
            raise InputError(f"{pat} does not exist: give a directory of runs, the runs, or a glob like 'logs/*.mcap'")
        else:
            _add(Path(pat), files, skipped, named=True)
    if not files:
        raise InputError(f"no .mcap, .bag or .csv runs (or ROS 2 bag directories) found at {', '.join(patterns)}"
                         + (f" (passed over: {', '.join(skipped[:5])})" if skipped else ""))
    return sorted(files, key=_counted)


def _add(p: Path, files: dict, skipped: list, named: bool) -> None:
    """``p``'s runs into ``files``: a run (or, ``named``, any file given by name) itself, a directory's
    runs; what is passed over into ``skipped``."""
    if _is_run(p) or (named and p.is_file()):
        files.setdefault(str(p), None)
    elif p.is_dir():
        for f in sorted(p.iterdir(), key=lambda f: _counted(f.name)):
            if _is_run(f):
                files.setdefault(str(f), None)
            elif f.is_dir():
                skipped.append(f"{f}/ (a directory in it: name it too, or a glob like '{p}/*/*.mcap')")
            elif not f.name.startswith("."):
                skipped.append(f"{f} (not a run)")
    else:
        skipped.append(f"{p} (not a run)")


def _counted(name: str) -> list:
    """A name's sort key with its numbers as numbers ("run_10" after "run_2")."""
    import re

    return [(0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", name)]


def _is_run(f: Path) -> bool:
    return f.suffix.lower() in (".mcap", ".csv", ".bag") or (f.is_dir() and (f / "metadata.yaml").is_file())


def run_job(path: str, vehicle_path: str, model: str, method: str, do_diagnose: bool) -> dict:
    """One run -> one row (plain types only: it crosses process and network boundaries)."""
    from host.errors import HostError
    from stid.load import load_file
    from stid.vehicle_file import load_vehicle

    row = {"run": path}
    t0 = time.perf_counter()
    try:
        vehicle = load_vehicle(vehicle_path)
        runs = load_file(path, vehicle)
        from stid.fit.dataset import V_MOVING

        if all(max(abs(r.vx.min()), abs(r.vx.max())) < V_MOVING for r in runs):
            # (a session's calibration run: every normal session directory made batch exit 3)
            row.update(error="", skipped="stands still throughout: nothing to fit (stid calibrate takes it)",
                       seconds=time.perf_counter() - t0)
            return row
        from stid.fit.fitting import fit

        res = fit(runs, vehicle, model, method)
        row.update({"model": res.model, "method": res.method, "converged": bool(res.converged),
                    "fitted": " ".join(res.names)})
        # the 95% intervals `stid fit` prints (none where the data do not determine the parameter): a
        # drift plot of standard errors drew bars a third of their width, and steps that are none
        for n, v, se, (lo, hi) in zip(res.names, res.values, res.stderr, res.ci95):
            row[n] = float(v)
            row[f"{n}_se"] = float(se)
            row[f"{n}_lo"], row[f"{n}_hi"] = float(lo), float(hi)
        for n, (v, _, _) in res.fixed.items():
            row[n] = float(v)
        for o, f in res.fit.items():
            row[f"fit_{o}"] = float(f)
        speeds = [p.vx for p in res.predictions]
        row["speed"] = float(sum(speeds) / len(speeds)) if speeds else float("nan")
        # the loader's warnings too: the count is what `stid fit` prints for the same file, the words
        # what it says (a run cut short was a bare "3")
        said = list(dict.fromkeys([*(w for r in runs for w in r.meta.get("warnings", [])), *res.warnings]))
        row["warnings"] = len(said)
        row["warning_text"] = " | ".join(said)
        row["below_floor"] = _below_floor(res, runs)
        if do_diagnose:
            from stid.diagnose import diagnose

            (d,) = diagnose(runs, vehicle, model)
            row["missing_effect"] = "+".join(d.named)  # (two when a pair is named)
        row["error"] = ""
    except (StidError, HostError, ValueError) as e:
        row["error"] = str(e)
    row["seconds"] = time.perf_counter() - t0
    return row


def _below_floor(res, runs) -> str:
    """Fit points the model is short of the run's noise floor, where that is beyond chance ("ay 12.3,
    r 4.1"), as `stid fit` says it; empty otherwise. A model that misses an effect drifts from run to
    run with the driving, not the car: the plain bicycle's Cf read 96-245 N/rad across one car's runs."""
    from stid.analysis.noise_floor import runs_below_floor

    return ", ".join(f"{o} {g:.1f}" for o, g in runs_below_floor(res, runs).items())


def _progress(done: int, total: int) -> None:
    if sys.stderr.isatty():
        sys.stderr.write(f"\r{done}/{total} runs")
        sys.stderr.flush()
        if done == total:
            sys.stderr.write("\n")


def run_batch(files, vehicle_path, model="bicycle", method="time", workers=None, scheduler=None,
              do_diagnose=False) -> list[dict]:
    jobs = [(f, vehicle_path, model, method, do_diagnose) for f in files]
    rows = []
    if scheduler:
        try:
            from dask.distributed import Client, as_completed as dask_completed
        except ImportError:
            raise InputError("--scheduler needs Dask: pip install 'stid[dask]'") from None
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as e:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            futures = [client.submit(run_job, *j, pure=False) for j in jobs]
            for k, fut in enumerate(dask_completed(futures), 1):
                rows.append(fut.result())
                _progress(k, len(jobs))
    else:
        workers = workers or min(len(jobs), os.cpu_count() or 1)
        if workers <= 1:
            for k, j in enumerate(jobs, 1):
                rows.append(run_job(*j))
                _progress(k, len(jobs))
        else:
            with ProcessPoolExecutor(max_workers=workers) as ex:
                futs = [ex.submit(run_job, *j) for j in jobs]
                for k, fut in enumerate(as_completed(futs), 1):
                    rows.append(fut.result())
                    _progress(k, len(jobs))
    order = {f: i for i, f in enumerate(files)}
    rows.sort(key=lambda r: order[r["run"]])
    return rows


def _check_writable(out: Path) -> None:
    """That the table can be written where asked, and in its format (InputError if not)."""
    why = unwritable(out.parent)
    if why:
        raise InputError(f"-o {out}: {why}; give an output in a directory you can write to")
    if out.suffix.lower() == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise InputError("writing Parquet needs pyarrow (pip install pyarrow); or give -o RESULTS.csv") from None


def write_table(rows, out: Path) -> None:
    import pandas as pd

    df = pd.DataFrame(rows)
    if "warnings" in df:  # a count (a run that failed has none: empty, not 0.0 for every run)
        df["warnings"] = df["warnings"].astype("Int64")
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".parquet":
        try:
            df.to_parquet(out, index=False)
        except ImportError:
            raise InputError("writing Parquet needs pyarrow (pip install pyarrow); or give -o RESULTS.csv") from None
    else:
        df.to_csv(out, index=False)


def drift_plot(rows, out: Path) -> Path | None:
    """Each fitted parameter across the runs, with its 95% interval: drift (wear, load, a servo
    changed) shows. A run whose model is far below its noise floor is drawn hollow and said: its
    values move with what the model misses, not with the car."""
    import math

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if not r.get("error")]
    params = list(dict.fromkeys(n for r in ok for n in str(r.get("fitted", "")).split() if n in r))
    if not ok or not params:
        return None
    fig, axes = plt.subplots(len(params), 1, figsize=(8, 2.1 * len(params) + 0.6), sharex=True, squeeze=False)
    units = {"Cf": "N/rad per axle", "Cr": "N/rad per axle", "Iz": "kg m^2", "tau_steer": "s", "x_acc": "m",
             "delay_s": "s", "sigma_f": "m", "sigma_r": "m", "delta0": "rad"}
    wrong = [bool(r.get("below_floor")) for r in ok]
    for ax, p in zip(axes[:, 0], params):
        for k, r in enumerate(ok):
            if p not in r or not math.isfinite(r[p]):
                continue
            lo, hi = r.get(f"{p}_lo", math.nan), r.get(f"{p}_hi", math.nan)
            known = math.isfinite(lo) and math.isfinite(hi)
            bar = [[r[p] - lo], [hi - r[p]]] if known else None
            ax.errorbar([k], [r[p]], yerr=bar, fmt="o" if known else "x", ms=4, color="C3" if wrong[k] else "C0",
                        mfc="none" if wrong[k] else "C0", capsize=3)
        ax.set_ylabel(f"{p} [{units.get(p, '')}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xticks(range(len(ok)), [Path(r["run"]).stem[:18] for r in ok], rotation=60, fontsize=7)
    # (an interval narrower than its dot shows as the caps alone: "no bar" had read as "not determined")
    title = "Parameters across runs (95% intervals as stid fit prints them, some narrower than the dot; x: no interval)"
    if any(wrong):
        title += ("\nhollow red: the model is far below that run's noise floor (it misses an effect): "
                  "those values move with it")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


PARTLY_FAILED = 3  # exit code: some runs fitted, some not (each named, and a row with its error)


def batch_cli(pattern, vehicle, model, method, workers, scheduler, output, do_diagnose, overwrite=False) -> int:
    if Path(output).suffix.lower() not in (".csv", ".parquet"):  # before hours of fitting, not after
        raise InputError(f"-o {output}: the table is written as .csv or .parquet; give a name ending in one")
    refuse_existing([output, Path(output).with_suffix(".drift.png")], "stid batch", overwrite)
    _check_writable(Path(output))  # before the fitting too: a trial user lost it to /proc/out.csv
    skipped: list = []
    files = find_runs(pattern, skipped)
    for what in skipped:
        print(f"note: passed over {what}", file=sys.stderr)
    if not Path(vehicle).exists():
        raise InputError(f"vehicle file {vehicle} does not exist")
    if workers is not None and workers < 1:
        raise InputError(f"--workers {workers}: give 1 or more (or leave it out: one per core)")
    from stid.models.model import Model
    from stid.vehicle_file import load_vehicle

    Model(model, load_vehicle(vehicle))  # a misspelt model is said once, before any run is fitted
    rows = run_batch(files, vehicle, model, method, workers, scheduler, do_diagnose)
    out = Path(output)
    write_table(rows, out)
    plot = drift_plot(rows, out.with_suffix(".drift.png"))
    failed = [r for r in rows if r["error"]]
    still = [r for r in rows if r.get("skipped")]
    print(f"{len(rows) - len(failed) - len(still)} of {len(rows)} runs fitted"
          + (f", {len(still)} standing still throughout passed over ({', '.join(Path(r['run']).name for r in still[:3])}"
             f"{' ...' if len(still) > 3 else ''})" if still else "")
          + f"; table {out}" + (f"; drift plot {plot}" if plot else ""), file=sys.stderr)
    short = [r for r in rows if not r["error"] and r.get("below_floor")]
    if short:
        print(f"  {len(short)} of them far below their noise floor with {model} (the column below_floor): it "
              "misses an effect there, and their values move with it; stid diagnose on one names it",
              file=sys.stderr)
    for r in failed:
        print(f"  {r['run']}: {r['error']}", file=sys.stderr)
    return 0 if not failed else PARTLY_FAILED if len(failed) < len(rows) else 1
