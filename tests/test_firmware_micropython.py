"""The firmware's own tests, run under the real MicroPython unix port."""

import binascii
import zlib

import pytest
from cobs import cobs

from conftest import MP_TESTS, VECTORS, run_micropython


def _assert_passed(proc):
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "FAIL" not in out, out
    assert " passed, 0 failed" in out, out


def test_micropython_encoder_matches_golden_vectors():
    _assert_passed(run_micropython(MP_TESTS / "mp_vectors.py", VECTORS))


def test_ring_buffer_semantics():
    _assert_passed(run_micropython(MP_TESTS / "mp_ring.py"))


def test_hot_path_does_not_allocate(stimulus_file):
    _assert_passed(run_micropython(MP_TESTS / "mp_heap.py", stimulus=stimulus_file, board=True))


@pytest.mark.parametrize("board", ["pico", "esp32"])
def test_four_wheel_hot_path_does_not_allocate(tmp_path, board):
    from conftest import simple_stimulus

    simple_stimulus(tmp_path / "stim4.bin", board=board, four_wheels=True)
    proc = run_micropython(MP_TESTS / "mp_heap.py", stimulus=tmp_path / "stim4.bin", board=True)
    _assert_passed(proc)
    assert "four hall sensors counted" in proc.stdout


@pytest.mark.parametrize("seed", [1, 2])
def test_viper_cobs_and_crc_agree_with_reference_libraries(seed):
    proc = run_micropython(MP_TESTS / "mp_cobs_random.py", 300, seed)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.split()
    assert len(lines) == 600
    for raw_hex, wire_hex in zip(lines[::2], lines[1::2]):
        raw, wire = binascii.unhexlify(raw_hex), binascii.unhexlify(wire_hex)
        assert wire[-1] == 0 and 0 not in wire[:-1]
        assert wire[:-1] == cobs.encode(raw)
        assert zlib.crc32(raw[:-4]) == int.from_bytes(raw[-4:], "little")
