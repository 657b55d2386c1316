"""The firmware's own tests, run under the real MicroPython unix port."""

import binascii
import os
import subprocess
import zlib

import pytest
from cobs import cobs

from conftest import BOARD, FIRMWARE, MP_TESTS, VECTORS, run_micropython, tool


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


def test_pulse_inputs_steer_timeout_and_hall_debounce(stimulus_file):
    # the steer value must not come back 9-17 min after the receiver is lost (ticks
    # wrap at 2^30 us), and a hall bounce must not count as a pulse
    _assert_passed(run_micropython(MP_TESTS / "mp_pulses.py", stimulus=stimulus_file, board=True))


def test_reset_cause_tells_a_reset_asked_for_from_the_watchdog_and_kbd_intr_is_restored(stimulus_file):
    _assert_passed(run_micropython(MP_TESTS / "mp_reset_cause.py", stimulus=stimulus_file, board=True))


def test_escape_sequence_and_safe_boot(stimulus_file, tmp_path):
    # run in tmp_path: the safe-boot flag file is written to the working directory
    env = dict(os.environ, MICROPYPATH=f"{BOARD}:{MP_TESTS}:{FIRMWARE}", STID_SIM_STIMULUS=str(stimulus_file))
    proc = subprocess.run([tool("micropython"), "-X", "heapsize=32M", str(MP_TESTS / "mp_escape.py")],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    _assert_passed(proc)


def test_escape_through_stdin_poll_without_allocation(stimulus_file):
    env = dict(os.environ, MICROPYPATH=f"{BOARD}:{MP_TESTS}:{FIRMWARE}", STID_SIM_STIMULUS=str(stimulus_file))
    proc = subprocess.run([tool("micropython"), "-X", "heapsize=32M", str(MP_TESTS / "mp_escape_live.py")],
                          input="noise\x03\x03STID-ESC STID-ESCAPE\n", capture_output=True, text=True,
                          env=env, timeout=60)
    _assert_passed(proc)
