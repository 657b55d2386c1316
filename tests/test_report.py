"""stid report: one self-contained HTML page with the chain, the figures and the diagnosis."""

import base64
import re
import subprocess

from conftest import REPO, tool
from simdata import random_steer_pair


def test_report_is_self_contained_and_tells_the_story(simdir, tmp_path):
    paths = random_steer_pair(simdir, ("actuator_lag", "accel_offset"))
    r = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "rep")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    assert r.stdout.strip().endswith("report.html")
    images = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(images) >= 7  # runs, error fall, time, Bode, |ay| bins, residual correlations, residual spectra
    assert all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    assert "src='http" not in page and 'src="http' not in page  # nothing fetched from outside
    for text in ("bicycle+actuator_lag", "accel_offset", "N/rad", "noise floor", "The error falls",
                 "Residual spectra against the noise floor", "The logged runs", "95% interval"):
        assert text in page, text
    assert "white-space:pre-wrap" in page  # the diagnosis text wraps instead of scrolling
    # every model of the chain has its parameters on the page (with intervals)
    chain = re.findall(r"<h3>([^<:]+): fit ay", page)
    assert len(chain) == 3 and chain[0] == "bicycle" and chain[-1].count("+") == 2, chain
    # the command the page says to run next runs, from another directory too (it named the
    # vehicle by its name and the runs without their directories)
    import html
    import shlex

    nxt = shlex.split(html.unescape(re.search(r"next: ([^<\n]*)", page).group(1)))
    assert nxt[:2] == ["stid", "fit"] and nxt[-2:] == ["--model", chain[-1]], nxt
    again = subprocess.run([tool("stid"), *nxt[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr


def test_a_report_directory_that_cannot_be_made_is_named_before_any_work(simdir, tmp_path):
    paths = random_steer_pair(simdir, ("actuator_lag", "accel_offset"))
    (tmp_path / "a_file").write_text("")
    r = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "a_file" / "rep")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("stid report: error: cannot make the report directory") and "-o" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    f = subprocess.run([tool("stid"), "report", *map(str, paths), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "a_file")],
                       capture_output=True, text=True, timeout=60)
    assert f.returncode == 2 and "is a file" in f.stderr and len(f.stderr.strip().splitlines()) == 1, f.stderr
