"""stid batch: many runs in parallel, one table, drift plots; bad runs are rows, not crashes."""

import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from conftest import REPO, tool
from simdata import random_steer_pair

VEHICLE = str(REPO / "docs" / "examples" / "rc8.toml")


@pytest.fixture
def season(simdir, tmp_path):
    d = tmp_path / "season"
    d.mkdir()
    for p in random_steer_pair(simdir) + random_steer_pair(simdir, ("actuator_lag",)):
        shutil.copy(p, d / p.name)
    (d / "broken.mcap").write_bytes(b"not an mcap file at all")
    return d


def test_batch_on_local_processes(season, tmp_path):
    out = tmp_path / "results.csv"
    r = subprocess.run([tool("stid"), "batch", str(season), "--vehicle", VEHICLE, "--workers", "2",
                        "--diagnose", "-o", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 3, r.stderr  # some runs fitted, one did not: a script must see it
    df = pd.read_csv(out)
    df[["error", "missing_effect"]] = df[["error", "missing_effect"]].fillna("")
    assert len(df) == 5
    good = df[df["error"] == ""]
    assert len(good) == 4
    assert set(good["missing_effect"]) == {"", "actuator_lag"}
    clean = good[good["missing_effect"] == ""]
    assert ((clean["Cf"] - 400).abs() < 12).all() and (clean["Cf_se"] > 0).all()
    assert "MCAP" in df[df["error"] != ""]["error"].iloc[0]
    assert (tmp_path / "results.drift.png").exists()
    assert "4 of 5 runs fitted" in r.stderr
    warned = pd.read_csv(out, dtype=str, keep_default_na=False)["warnings"]
    assert all(w == "" or w.isdigit() for w in warned), list(warned)  # a count, not 0.0 (a failed run: empty)
    # the intervals stid fit prints, and which runs the model misses something in (a trial's plain
    # bicycle drifted 96-245 N/rad across one car's runs, drawn with bars of one standard error)
    for n in ("Cf", "Cr", "Iz"):
        assert ((good[f"{n}_lo"] < good[n]) & (good[n] < good[f"{n}_hi"])).all(), good[[n, f"{n}_lo", f"{n}_hi"]]
    short = good["below_floor"].fillna("") != ""
    assert list(short) == list(good["missing_effect"] == "actuator_lag"), good[["run", "below_floor"]]
    assert "far below their noise floor with bicycle" in r.stderr, r.stderr


def test_batch_says_a_misspelt_model_once_before_fitting_and_draws_every_parameter(season, tmp_path):
    """`--model bicycle+foo` printed one error per run and wrote a table of errors; and the drift plot
    drew Cf, Cr and Iz only, so a servo changed between sessions (its tau_steer in the table) never
    showed."""
    r = subprocess.run([tool("stid"), "batch", str(season), "--vehicle", VEHICLE, "--model", "bicycle+foo",
                        "-o", str(tmp_path / "m.csv")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "unknown effect 'foo'" in r.stderr and not (tmp_path / "m.csv").exists(), r.stderr
    from stid.batch import drift_plot
    import matplotlib.image

    rows = [{"run": f"r{k}", "fitted": "Cf Iz tau_steer", "Cf": 400.0, "Cf_lo": 398.0, "Cf_hi": 402.0, "Iz": 0.25,
             "Iz_lo": 0.24, "Iz_hi": 0.26, "tau_steer": 0.045 + 0.035 * (k > 1), "tau_steer_lo": float("nan"),
             "tau_steer_hi": float("nan"), "below_floor": "", "error": ""} for k in range(4)]
    png = drift_plot(rows, tmp_path / "d.png")
    height, width = matplotlib.image.imread(png).shape[:2]
    one = drift_plot([{k: v for k, v in r.items()} | {"fitted": "Cf"} for r in rows], tmp_path / "one.png")
    assert height > 2.5 * matplotlib.image.imread(one).shape[0] - 200  # three panels where one was asked


def test_batch_without_runs_fails_cleanly(tmp_path):
    r = subprocess.run([tool("stid"), "batch", str(tmp_path / "nothing*.mcap"), "--vehicle", VEHICLE],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "nothing matches" in r.stderr and "Traceback" not in r.stderr
    # a table format it does not write is refused before any fitting (it wrote CSV text as .xlsx)
    x = subprocess.run([tool("stid"), "batch", str(tmp_path), "--vehicle", VEHICLE, "-o", str(tmp_path / "t.xlsx")],
                       capture_output=True, text=True)
    assert x.returncode == 2 and ".csv or .parquet" in x.stderr and not (tmp_path / "t.xlsx").exists(), x.stderr


@pytest.mark.dask
def test_batch_on_a_local_dask_cluster(season, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True)
    try:
        out = tmp_path / "dask.csv"
        r = subprocess.run([tool("stid"), "batch", str(season), "--vehicle", VEHICLE, "--scheduler",
                            cluster.scheduler_address, "-o", str(out)], capture_output=True, text=True, timeout=600)
        assert r.returncode == 3, r.stderr
        df = pd.read_csv(out)
        assert len(df) == 5 and df["error"].isna().sum() == 4
    finally:
        cluster.close()


def test_runs_are_taken_in_the_order_their_names_count(tmp_path):
    """Sorted as text, a trial's session 10 (run_10a) came before sessions 1 and 2 on the drift plot."""
    from stid.batch import find_runs

    for name in ("run_10a.mcap", "run_2a.mcap", "run_1b.mcap", "run_1a.mcap", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    assert [p.rsplit("/", 1)[1] for p in find_runs(str(tmp_path))] == ["run_1a.mcap", "run_1b.mcap", "run_2a.mcap",
                                                                       "run_10a.mcap"]


def test_a_glob_the_shell_expanded_is_taken_and_a_missing_directory_is_said(season, tmp_path):
    """`stid batch logs/run_1*.mcap` unquoted: the shell gives the files, and argparse refused them as
    "unrecognized arguments"; a directory that does not exist was "no ... runs found"."""
    files = sorted(str(p) for p in season.glob("random_steer*.mcap"))[:2]
    r = subprocess.run([tool("stid"), "batch", *files[::-1], "--vehicle", VEHICLE, "--workers", "1", "-o",
                        str(tmp_path / "two.csv")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "2 of 2 runs fitted" in r.stderr, r.stderr
    from stid.batch import _counted

    assert list(pd.read_csv(tmp_path / "two.csv")["run"]) == sorted(files, key=_counted)  # as their names count
    gone = subprocess.run([tool("stid"), "batch", str(tmp_path / "nosuchdir"), "--vehicle", VEHICLE, "-o",
                           str(tmp_path / "x.csv")], capture_output=True, text=True, timeout=60)
    assert gone.returncode == 2 and "nosuchdir does not exist" in gone.stderr, gone.stderr


def test_every_argument_is_read_and_what_is_passed_over_is_said(season, simdir, tmp_path):
    """A trial user's `stid batch day1/ day2/` read day1 alone (13 runs of day2 dropped, exit 0); two
    quoted globs were 'does not exist'; a subdirectory and a file that is no run were passed over
    without a word; a session's stand-still run (the one `stid calibrate` takes) made every normal
    session's batch exit 3; and an output where nothing can be written was found after the fitting."""
    from simdata import sim_run

    day1, day2 = tmp_path / "day1", tmp_path / "day2"
    day1.mkdir()
    (day1 / "older").mkdir()
    (day1 / "notes.txt").write_text("tyres new\n")
    files = sorted(p for p in season.glob("*.mcap") if p.name != "broken.mcap")
    shutil.copy(files[0], day1 / files[0].name)
    shutil.copy(sim_run(simdir, "standstill", duration=4.0), day1 / "still.mcap")
    shutil.copytree(season, day2, ignore=shutil.ignore_patterns("broken.mcap", files[0].name))
    out = tmp_path / "all.csv"
    r = subprocess.run([tool("stid"), "batch", str(day1), str(day2 / "*.mcap"), "--vehicle", VEHICLE, "-o", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    df = pd.read_csv(out)
    assert sorted(pd.Series(df["run"]).map(lambda p: p.rsplit("/", 1)[1])) == sorted([*(f.name for f in files),
                                                                                     "still.mcap"])
    still = df[df["run"].str.endswith("still.mcap")]
    assert still["error"].isna().all() and "stands still throughout" in still["skipped"].iloc[0]
    assert f"{len(files)} of {len(files) + 1} runs fitted, 1 standing still throughout passed over" in r.stderr
    assert "passed over " + str(day1 / "older") + "/" in r.stderr and str(day1 / "notes.txt") + " (not a run)" in r.stderr
    for bad, words in ((tmp_path / "notes.txt" / "x.csv", "is not a directory"), (Path("/proc/x.csv"), "cannot write")):
        (tmp_path / "notes.txt").write_text("")
        w = subprocess.run([tool("stid"), "batch", str(day1), "--vehicle", VEHICLE, "-o", str(bad)],
                           capture_output=True, text=True, timeout=60)
        assert w.returncode == 2 and words in w.stderr and "runs fitted" not in w.stderr, w.stderr
