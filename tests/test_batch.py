"""stid batch: many runs in parallel, one table, drift plots; bad runs are rows, not crashes."""

import shutil
import subprocess

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


def test_batch_without_runs_fails_cleanly(tmp_path):
    r = subprocess.run([tool("stid"), "batch", str(tmp_path / "nothing*.mcap"), "--vehicle", VEHICLE],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "no .mcap, .bag or .csv runs" in r.stderr and "Traceback" not in r.stderr
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
