"""The benchmark harness runs end to end (quick sizes: it checks the harness, not the goals;
`make bench` measures the goals)."""

import json
import subprocess
import sys

import pytest

from conftest import REPO


# ~2.5 min of simulations and fits: `make bench` runs the same harness for real; this checks it
# in the slow set (`pytest -m slow`) so that `make test` stays within its ~10 minutes.
@pytest.mark.slow
def test_make_bench_quick_mode_produces_its_table():
    r = subprocess.run([sys.executable, "-m", "benchmarks.run", "--quick"], cwd=REPO, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads((REPO / "benchmarks" / "results" / "quick.json").read_text())
    parts = {row[0] for row in doc["rows"]}
    assert {"logger", "firmware", "fit", "diagnose", "accuracy", "scaling"} <= parts
    assert all(len(row) == 5 for row in doc["rows"])
    md = (REPO / "benchmarks" / "results" / "quick.md").read_text()
    assert md.startswith("| part | figure | measured | goal | met |")
