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


@pytest.mark.parametrize("rate", [8, 10000])
def test_a_rate_the_firmware_refuses_at_boot_is_refused_before_flashing(rate):
    """`stid flash --rate 8` printed a plan that flashed a board whose App then raised at boot
    (the board sat at the REPL); the firmware's own range is read from its source here."""
    import re

    src = (FIRMWARE / "app.py").read_text()
    lo, hi = map(int, re.search(r"if not (\d+) <= rate_hz <= (\d+)", src).groups())
    assert fl.FIRMWARE_RATES == (lo, hi)
    with pytest.raises(StidError, match=f"firmware samples at {lo} to {hi} Hz"):
        fl.check_link("pico", rate, 1)


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
    ("STIDVER 1 26 1 rp2", True, False), ("STIDVER 1 24 0 esp32", True, True), ("STIDVER 1 26 0 esp32", True, False)])
def test_micropython_version_gate(answer, ok, note):
    board = "pico" if "rp2" in answer else "esp32"
    facts = fl.parse_probe("noise\r\n" + answer + "\r\nSTIDMEM 190000 800000\r\n", board, None)
    if not ok:
        with pytest.raises(StidError, match="needs 1.23 or newer"):
            fl.check_micropython(facts.version, board)
        return
    text = fl.check_micropython(facts.version, board)
    assert bool(text) == note
    if note:
        assert "1.26" in text and ("soft" in text if board == "pico" else "esp32.PCNT" in text)


def test_board_side_scripts_remove_main_and_stale_py_and_hash(tmp_path):
    # run the scripts mpremote would exec, on the MicroPython unix port, in a fake board dir
    for m in fl.COMPILED_MODULES:
        (tmp_path / f"{m}.py").write_text("# stale\n")
    (tmp_path / "main.py").write_text("# old main\n")
    (tmp_path / "boot.py").write_text("# keep\n")
    (tmp_path / "codec.mpy").write_bytes(b"M\x06\x00\x1f" + bytes(range(40)))
    proc = subprocess.run([tool("micropython"), "-c", fl._prepare_script()], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    # main.py goes too: until the copy is verified the board boots to the REPL
    assert sorted(p.name for p in tmp_path.iterdir()) == ["boot.py", "codec.mpy"]
    (tmp_path / "main.py").write_text("# new main\n")
    files = [tmp_path / "codec.mpy", tmp_path / "main.py"]
    proc = subprocess.run([tool("micropython"), "-c", fl._hash_script([f.name for f in files])], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    fl.verify(proc.stdout, files)  # matches
    (tmp_path / "main.py").write_text("# changed after the copy\n")
    with pytest.raises(StidError, match="differs from the build for main.py"):
        fl.verify(proc.stdout, files)
    assert hashlib.sha256(b"").hexdigest() not in proc.stdout


# -- a whole flash, onto a simulated board behind a stand-in for mpremote -----------------
PICO = {"platform": "rp2", "version": [1, 26, 0], "heap": 190_000, "fs_size": 868_352}
ESP32 = {"platform": "esp32", "version": [1, 26, 0], "heap": 110_000, "fs_size": 2_097_152}


@pytest.fixture(scope="session")
def fake_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("fake_mpremote")


@pytest.fixture
def board(tmp_path, monkeypatch, fake_cache):
    """A board folder behind tests/fake_mpremote.py; `board.set(**state)` says what it is."""
    import json
    import sys
    from pathlib import Path

    folder = tmp_path / "board"
    folder.mkdir()
    wrapper = tmp_path / "mpremote"
    wrapper.write_text(f"#!/bin/sh\nexec {sys.executable} {Path(__file__).parent / 'fake_mpremote.py'} \"$@\"\n")
    wrapper.chmod(0o755)
    real = fl._tool
    monkeypatch.setattr(fl, "_tool", lambda name: str(wrapper) if name == "mpremote" else real(name))
    monkeypatch.setenv("FAKE_BOARD", str(folder))
    monkeypatch.setenv("FAKE_CACHE", str(fake_cache))

    class Board:
        path = folder

        def set(self, **state):
            (folder / ".board.json").write_text(json.dumps(state))

        def files(self):
            return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))

        def calls(self):
            f = folder / ".calls"
            return f.read_text().splitlines() if f.exists() else []

    b = Board()
    b.set(**PICO)
    return b


def _flash(board_name, **kw):
    import io

    out = io.StringIO()
    code = fl.flash(board_name, out=out, **kw)
    return code, out.getvalue()


ALL_FILES = sorted([f"{m}.mpy" for m in fl.COMPILED_MODULES] + ["config.py", "main.py"])


def test_flash_onto_a_simulated_pico_verifies_and_reads_back_the_versions(board):
    code, out = _flash("pico")
    assert code == 0
    assert board.files() == ALL_FILES
    fw, proto = fl.local_versions()
    assert "firmware %d.%d.%d, protocol %d read back" % (*fw, proto) in out
    # gc.mem_free() was asked of the board (heap 190 kB): the budget line shows what it said
    free = float(out.split("of the board's ")[1].split(" kB")[0])
    assert 150 < free < 190
    kinds = [c.split()[0] + (" " + c.split()[2] if c.startswith("fs") else "") for c in board.calls()]
    # main.py is removed before anything is copied and copied back last
    assert [c.split()[0] for c in board.calls()] == ["exec", "exec", "fs", "exec", "exec", "fs", "exec", "reset"]
    assert "main.py" in board.calls()[1] and board.calls()[5].endswith("main.py :")
    assert len(kinds) == 8
    assert "BOARD = 'pico'" in (board.path / "config.py").read_text()


def test_a_board_of_another_platform_is_refused_before_anything_is_written(board):
    board.set(**ESP32)
    with pytest.raises(StidError, match=r"runs MicroPython for 'esp32'.*not a pico.*use --board esp32"):
        _flash("pico")
    assert board.files() == []
    assert len(board.calls()) == 1  # the probe only


def test_garbage_to_the_version_probe_is_a_clear_message_and_the_board_can_be_flashed(board):
    for answer in ("\x00\xff\x13garbage>>> ", "STIDVER 1 26\r\n", "Traceback (most recent call last):\r\n",
                   "STIDVER 1 26 0 rp2\r\nSTIDMEM lots\r\n"):
        board.set(**PICO, answer=answer)
        with pytest.raises(StidError, match="did not answer the version probe.*Nothing was written"):
            _flash("pico")
        assert board.files() == []
    board.set(**PICO)
    assert _flash("pico")[0] == 0 and board.files() == ALL_FILES


def test_a_full_filesystem_is_refused_before_the_copy(board):
    (board.path / "log.bin").write_bytes(bytes(850_000))  # a user's file fills the flash: 16 kB left
    with pytest.raises(StidError, match=r"filesystem has \d+\.\d kB free.*needs.*Nothing was written"):
        _flash("pico")
    assert board.files() == ["log.bin"]


def test_a_full_filesystem_found_during_the_copy_leaves_a_board_that_can_be_flashed(board):
    # a port that cannot tell its free space (no os.statvfs): the copy itself runs out
    (board.path / "main.py").write_text("import app\napp.main()\n")  # an earlier flash
    (board.path / "log.bin").write_bytes(bytes(850_000))
    board.set(**PICO, statvfs=False)
    with pytest.raises(StidError, match="filesystem is full: the copy stopped half way.*boots to the REPL"):
        _flash("pico")
    assert "main.py" not in board.files()  # so it boots to the REPL, not into half a firmware
    (board.path / "log.bin").unlink()
    assert _flash("pico")[0] == 0 and board.files() == ALL_FILES


def test_a_flash_interrupted_half_way_leaves_a_board_that_can_be_flashed(board):
    (board.path / "main.py").write_text("import app\napp.main()\n")
    board.set(**PICO, cp_fails_after=3)
    with pytest.raises(StidError, match=r"copy stopped half way \(failed to access.*can be flashed again"):
        _flash("pico")
    assert "main.py" not in board.files()
    half = board.path / f"{fl.COMPILED_MODULES[3]}.mpy"
    assert half.exists() and half.stat().st_size > 0  # written in part
    board.set(**PICO)
    code, out = _flash("pico")
    assert code == 0 and board.files() == ALL_FILES and "read back" in out


def test_a_module_the_board_cannot_import_fails_the_read_back(board, monkeypatch):
    # the .mpy files of another architecture (a wrong -march): the SHA-256 of the copy
    # matches the build, only importing on the board finds it
    monkeypatch.setitem(fl.ARCH, "pico", "xtensawin")
    with pytest.raises(StidError, match="does not import there.*incompatible .mpy.*boots to the REPL"):
        _flash("pico")
    assert "main.py" not in board.files()


def test_read_back_compares_firmware_and_protocol_versions():
    fw, proto = fl.local_versions()
    fl.check_readback("STIDFW %d %d %d %d\r\n" % (*fw, proto))
    with pytest.raises(StidError, match=r"reports firmware 0\.1\.0, protocol 2"):
        fl.check_readback("STIDFW 0 1 0 2\r\n")


def test_a_rate_whose_ring_does_not_fit_the_heap_the_board_reports_is_refused(board):
    # 5 kHz on a Pico: a 1.25 s ring is 6250 x 30 B = 187.5 kB, the heap ~185 kB
    assert fl.ring_bytes(5000, 10, 1) == 187_500
    with pytest.raises(StidError, match=r"187\.5 kB.*does not fit.*Use --rate (\d+) or less") as e:
        _flash("pico", rate_hz=5000)
    assert board.files() == []
    most = int(str(e.value).split("Use --rate ")[1].split()[0])
    free = fl.ring_bytes(most, 10, 1) + fl.FIRMWARE_HEAP_BYTES
    assert 1_000_000 % most == 0 and free < 190_000
    code, out = _flash("pico", rate_hz=most)
    assert code == 0 and f"RATE_HZ = {most}" in (board.path / "config.py").read_text()


def test_four_wheels_reach_config_the_link_and_the_heap_budget(board):
    code, out = _flash("pico", rate_hz=1000, wheels=4)
    assert code == 0 and "WHEELS = 4" in (board.path / "config.py").read_text()
    assert "46.1 B/sample" in out and "x 48 B" in out  # 44-byte records (+ 4 B index in the ring)
    with pytest.raises(StidError, match="--wheels 3"):
        fl.check_link("pico", 500, 10, wheels=3)
    assert stid_main(["flash", "--board", "esp32", "--wheels", "4", "--rate", "2000", "--dry-run"]) != 0


def test_dry_run_prints_a_plan_that_flashes_when_run_as_printed(board, tmp_path, capsys):
    build = tmp_path / "build"
    assert stid_main(["flash", "--board", "pico", "--dry-run", "--wheels", "4", "--build-dir", str(build)]) == 0
    script = capsys.readouterr().out
    assert not build.exists() and board.files() == [] and board.calls() == []  # nothing done
    (tmp_path / "plan.sh").write_text(script)
    proc = subprocess.run(["sh", str(tmp_path / "plan.sh")], capture_output=True, text=True)  # (POSIX sh: dash here)
    assert proc.returncode == 0, proc.stderr
    assert board.files() == ALL_FILES and "WHEELS = 4" in (board.path / "config.py").read_text()
    fw, proto = fl.local_versions()
    assert "STIDFW %d %d %d %d" % (*fw, proto) in proc.stdout  # the read-back ran
    for f in (f for f in ALL_FILES if f.endswith(".mpy")):  # the board holds what the printed commands built
        assert (board.path / f).read_bytes() == (build / f).read_bytes()


@pytest.mark.parametrize("state, said", [
    (dict(ESP32), "not a pico"),  # another board
    (dict(PICO, version=[1, 22, 2]), "MicroPython 1.23 or newer"),
    (dict(PICO, heap=80_000), "lower --rate"),  # gc.mem_free() measured on the unix port's 80 kB heap
    (dict(PICO, answer="Traceback (most recent call last):\r\n"), "did not answer"),
])
def test_the_printed_plan_checks_the_boards_answers_as_stid_flash_does(board, tmp_path, capsys, state, said):
    """The dry run's script stops where stid flash would, with the same advice, and nothing
    is written to the board (the checks of the probe come before main.py is removed)."""
    build = tmp_path / "build"
    assert stid_main(["flash", "--board", "pico", "--dry-run", "--build-dir", str(build)]) == 0
    (tmp_path / "plan.sh").write_text(capsys.readouterr().out)
    (board.path / "main.py").write_text("# the firmware flashed before\n")
    board.set(**state)
    proc = subprocess.run(["sh", str(tmp_path / "plan.sh")], capture_output=True, text=True)
    assert proc.returncode != 0 and said in proc.stderr, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("stid flash: ")
    assert board.files() == ["main.py"] and [c.split()[0] for c in board.calls()] == ["exec"]


def test_the_printed_plan_without_a_board_says_what_stid_flash_says(board, tmp_path, capsys):
    """No board plugged in: the script stopped under `set -e` inside its probe with mpremote's
    'no device found' alone, where stid flash says what to do."""
    build = tmp_path / "build"
    assert stid_main(["flash", "--board", "pico", "--dry-run", "--build-dir", str(build)]) == 0
    (tmp_path / "plan.sh").write_text(capsys.readouterr().out)
    (tmp_path / "mpremote").write_text("#!/bin/sh\necho 'mpremote: no device found' >&2\nexit 1\n")
    proc = subprocess.run(["sh", str(tmp_path / "plan.sh")], capture_output=True, text=True)
    assert proc.returncode != 0, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("stid flash: 'mpremote connect auto' failed (mpremote: no device found)"), proc.stderr
    assert "Is the board plugged in" in last and "--port" in last, proc.stderr


def test_the_printed_plan_stops_on_a_copy_that_differs_from_the_build(board, tmp_path, capsys):
    build = tmp_path / "build"
    assert stid_main(["flash", "--board", "pico", "--dry-run", "--build-dir", str(build)]) == 0
    script = capsys.readouterr().out
    # the board's filesystem changes a byte of what it was sent (a damaged copy): the plan's
    # copy step is followed by one that spoils ring.mpy, as a flaky flash would
    copy = next(line for line in script.splitlines() if " fs cp " in line and "ring.mpy" in line)
    spoil = f"printf 'x' | dd of={board.path / 'ring.mpy'} bs=1 seek=20 conv=notrunc 2>/dev/null"
    (tmp_path / "plan.sh").write_text(script.replace(copy, copy + "\n" + spoil))
    proc = subprocess.run(["sh", str(tmp_path / "plan.sh")], capture_output=True, text=True)
    assert proc.returncode != 0 and "differs from the build for ring.mpy" in proc.stderr, proc.stderr
    assert "main.py" not in board.files()  # the board boots to the REPL: it can be flashed again
