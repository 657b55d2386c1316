"""Every firmware module compiles for the real targets, and `stid flash` says
exactly what it would do."""

import subprocess

import pytest

from conftest import FIRMWARE, tool
from stid import flash as flash_mod
from stid.cli import main as stid_main

MODULES = sorted(p for p in FIRMWARE.glob("*.py"))


@pytest.mark.parametrize("arch", ["armv6m", "xtensawin"])
def test_every_module_compiles_with_mpy_cross(arch, tmp_path):
    assert len(MODULES) >= 7
    for src in MODULES:
        out = tmp_path / (src.stem + ".mpy")
        proc = subprocess.run([tool("mpy-cross"), f"-march={arch}", "-o", str(out), str(src)],
                              capture_output=True, text=True)
        assert proc.returncode == 0, f"{src.name} for {arch}: {proc.stderr}"
        assert out.stat().st_size > 0


def test_flash_dry_run_prints_the_commands(capsys):
    assert stid_main(["flash", "--board", "pico", "--port", "/dev/ttyACM0", "--dry-run"]) == 0
    out = capsys.readouterr().out
    for mod in flash_mod.COMPILED_MODULES:
        assert f"{mod}.mpy" in out
    assert "-march=armv6m" in out
    assert "mpremote connect /dev/ttyACM0 fs cp" in out
    assert "BOARD = 'pico'" in out


def test_flash_esp32_uses_xtensawin(capsys):
    assert stid_main(["flash", "--board", "esp32", "--dry-run"]) == 0
    assert "-march=xtensawin" in capsys.readouterr().out


def test_flash_to_missing_port_fails_cleanly(capsys):
    code = stid_main(["flash", "--board", "pico", "--port", "/dev/does-not-exist"])
    err = capsys.readouterr().err
    assert code != 0
    assert "error:" in err and "Traceback" not in err
