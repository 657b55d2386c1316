"""The C codec, built by gcc with sanitizers, against the golden vectors."""

import shutil
import subprocess

import pytest

from conftest import REPO


@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None, reason="no C compiler")
def test_c_codec_passes_golden_vectors():
    proc = subprocess.run(["make", "-s", "-C", str(REPO / "firmware" / "c"), "test"],
                          capture_output=True, text=True, timeout=180)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert " passed, 0 failed" in out, out
