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
from stid.output_paths import refuse_existing


def find_runs(pattern: str) -> list[str]:
    p = Path(pattern)
    if p.is_dir():
        files = sorted(str(f) for f in p.iterdir() if _is_run(f))
    else:
        files = sorted(f for f in glob.glob(pattern) if _is_run(Path(f)))
    if not files:
        raise InputError(f"no .mcap, .bag or .csv runs (or ROS 2 bag directories) found at {pattern!r}")
    return files


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
        from stid.fit.fitting import fit

        res = fit(runs, vehicle, model, method)
        row.update({"model": res.model, "method": res.method, "converged": bool(res.converged)})
        for n, v, se in zip(res.names, res.values, res.stderr):
            row[n] = float(v)
            row[f"{n}_se"] = float(se)
        for n, (v, _, _) in res.fixed.items():
            row[n] = float(v)
        for o, f in res.fit.items():
            row[f"fit_{o}"] = float(f)
        speeds = [p.vx for p in res.predictions]
        row["speed"] = float(sum(speeds) / len(speeds)) if speeds else float("nan")
        # the loader's warnings too: the count is what `stid fit` prints for the same file
        row["warnings"] = len(res.warnings) + sum(len(r.meta.get("warnings", [])) for r in runs)
        if do_diagnose:
            from stid.diagnose import diagnose

            (d,) = diagnose(runs, vehicle, model)
            row["missing_effect"] = "+".join(d.named)  # (two when a pair is named)
        row["error"] = ""
    except (StidError, HostError, ValueError) as e:
        row["error"] = str(e)
    row["seconds"] = time.perf_counter() - t0
    return row


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


def drift_plot(rows, out: Path, params=("Cf", "Cr", "Iz")) -> Path | None:
    """Each parameter across the runs, with its standard error: drift (wear, load) shows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if not r.get("error") and all(p in r for p in params)]
    if not ok:
        return None
    fig, axes = plt.subplots(len(params), 1, figsize=(8, 2.3 * len(params)), sharex=True)
    x = range(len(ok))
    units = {"Cf": "N/rad (per axle)", "Cr": "N/rad (per axle)", "Iz": "kg m^2"}
    for ax, p in zip(axes, params):
        ax.errorbar(list(x), [r[p] for r in ok], yerr=[r.get(f"{p}_se", 0) for r in ok], fmt="o", ms=3)
        ax.set_ylabel(f"{p} [{units.get(p, '')}]")
        ax.grid(alpha=0.3)
    axes[-1].set_xticks(list(x), [Path(r["run"]).stem[:18] for r in ok], rotation=60, fontsize=7)
    fig.suptitle("Parameters across runs (±1 standard error)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


PARTLY_FAILED = 3  # exit code: some runs fitted, some not (each named, and a row with its error)


def batch_cli(pattern, vehicle, model, method, workers, scheduler, output, do_diagnose, overwrite=False) -> int:
    if Path(output).suffix.lower() not in (".csv", ".parquet"):  # before hours of fitting, not after
        raise InputError(f"-o {output}: the table is written as .csv or .parquet; give a name ending in one")
    refuse_existing([output, Path(output).with_suffix(".drift.png")], "stid batch", overwrite)
    files = find_runs(pattern)
    if not Path(vehicle).exists():
        raise InputError(f"vehicle file {vehicle} does not exist")
    rows = run_batch(files, vehicle, model, method, workers, scheduler, do_diagnose)
    out = Path(output)
    write_table(rows, out)
    plot = drift_plot(rows, out.with_suffix(".drift.png"))
    failed = [r for r in rows if r["error"]]
    print(f"{len(rows) - len(failed)} of {len(rows)} runs fitted; table {out}"
          + (f"; drift plot {plot}" if plot else ""), file=sys.stderr)
    for r in failed:
        print(f"  {r['run']}: {r['error']}", file=sys.stderr)
    return 0 if not failed else PARTLY_FAILED if len(failed) < len(rows) else 1
