"""`stid flash` knows the board: link budget, MicroPython version, stale files, verify."""

import ast
import hashlib
import subprocess

import pytest

from conftest import FIRMWARE, tool
from stid import flash as fl
from stid.cli import main as stid_main
from stid.errors import StidError


def test_the_old_esp32_default_would_be_refused(monkeypatch):
    # 500 Hz of 26-byte records with framing is 500 * 28.1 B * 10 bit = 140.5 kbit/s:
    # the ESP32 console's 115200 baud cannot carry it (the loss the issue measured)
    assert 500 * (26 + 21 / 10) * 10 > 115200
    monkeypatch.setitem(fl.LINKS, "esp32", fl.Link("uart", 115200, 11520.0))
    with pytest.raises(StidError, match=r"more than 80%.*Use --rate (\d+)"):
        fl.check_link("esp32", 500, 10)


def test_default_rate_fits_every_board():
    for board in fl.LINKS:
        line = fl.check_link(board, 500, 10)
        share = int(line.rsplit(": ", 1)[1].split("%")[0])
        assert share <= 80


def test_refused_rate_names_the_arithmetic_and_a_rate_that_fits(capsys):
    assert stid_main(["flash", "--board", "esp32", "--rate", "4000", "--dry-run"]) != 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "of the line" in err and "kB/s" in err
    most = int(err.split("Use --rate ")[1].split()[0])
    # the suggested rate fits and has a whole-µs period; the next such rate does not fit
    assert 1000 < most < 4000 and 1_000_000 % most == 0
    above = min(r for r in range(most + 1, 4001) if 1_000_000 % r == 0)
    assert fl.stream_bytes_per_s(most, 10) <= 0.8 * 92160 < fl.stream_bytes_per_s(above, 10)


def test_rate_must_give_a_whole_microsecond_period():
    with pytest.raises(StidError, match="whole number of µs"):
        fl.check_link("pico", 300, 10)


def test_links_match_the_firmware_profiles():
    # stid flash's budget uses the link the firmware sets up (boards.py PROFILES)
    tree = ast.parse((FIRMWARE / "boards.py").read_text())
    profiles = next(ast.literal_eval(n.value) for n in tree.body
                    if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "PROFILES")
    for board, link in fl.LINKS.items():
        assert profiles[board]["link"]["kind"] == link.kind
        assert profiles[board]["link"]["baud"] == link.baud
    app_tree = ast.parse((FIRMWARE / "app.py").read_text())
    escape = next(ast.literal_eval(n.value) for n in app_tree.body
                  if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "ESCAPE")
    assert escape == fl.ESCAPE


@pytest.mark.parametrize("answer, ok, note", [
    ("STIDVER 1 22 2 rp2", False, False), ("STIDVER 1 25 0 rp2", True, True),
    ("STIDVER 1 26 1 rp2", True, False), ("STIDVER 1 24 0 esp32", True, False)])
def test_micropython_version_gate(answer, ok, note):
    board = "pico" if "rp2" in answer else "esp32"
    if not ok:
        with pytest.raises(StidError, match="needs 1.23 or newer"):
            fl.check_micropython(answer, board)
        return
    ver, text = fl.check_micropython("noise\r\n" + answer + "\r\n", board)
    assert bool(text) == note
    if note:
        assert "soft" in text and "1.26" in text


def test_board_side_scripts_remove_stale_py_and_hash(tmp_path):
    # run the scripts mpremote would exec, on the MicroPython unix port, in a fake board dir
    for m in fl.COMPILED_MODULES:
        (tmp_path / f"{m}.py").write_text("# stale\n")
    (tmp_path / "main.py").write_text("# keep\n")
    (tmp_path / "codec.mpy").write_bytes(b"M\x06\x00\x1f" + bytes(range(40)))
    proc = subprocess.run([tool("micropython"), "-c", fl._cleanup_script()], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["codec.mpy", "main.py"]
    files = [tmp_path / "codec.mpy", tmp_path / "main.py"]
    proc = subprocess.run([tool("micropython"), "-c", fl._hash_script([f.name for f in files])], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    fl.verify(proc.stdout, files)  # matches
    (tmp_path / "main.py").write_text("# changed after the copy\n")
    with pytest.raises(StidError, match="differs from the build for main.py"):
        fl.verify(proc.stdout, files)
    assert hashlib.sha256(b"").hexdigest() not in proc.stdout
