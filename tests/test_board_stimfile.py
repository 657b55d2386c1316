"""The simulated board reads its stimulus file through small windows (hil_sim/board/stimfile.py)
instead of holding it in MicroPython's heap: the firmware's bytes must not change, reloading
a window must not allocate (the firmware's heap test runs through it), and a run must fit a
heap smaller than its stimulus."""

import json
import subprocess

import numpy as np
import pytest
from conftest import BOARD, FIRMWARE, MP_TESTS, run_micropython, simple_stimulus, tool

from hil_sim.firmware_runner import firmware_env
from hil_sim.manoeuvres import Plan
from hil_sim.run import SimConfig, write_stimulus
from host.frame_decoder import FrameDecoder
from host import protocol as p

WHOLE = 10**9  # more rows than any file here: the board loads the whole file, as it used to


def _assert_passed(proc):
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "FAIL" not in out and " passed, 0 failed" in out, out


@pytest.mark.parametrize("board", ["pico", "esp32"])
def test_window_reloads_allocate_nothing_and_read_the_file(tmp_path, monkeypatch, board):
    stim = tmp_path / "stim.bin"
    simple_stimulus(stim, board=board, four_wheels=True)
    monkeypatch.setenv("STID_SIM_BOARD", json.dumps({"stim_rows": 3}))
    _assert_passed(run_micropython(MP_TESTS / "mp_stim_window.py", stimulus=stim, board=True))


def _firmware_bytes(stim, tmp_path, cfg, opts, heap="8M"):
    # os.urandom fixed (the HELLO's boot_id is random on every boot), so two runs can be compared
    shim = tmp_path / "shim"
    shim.mkdir(exist_ok=True)
    (shim / "os.py").write_text("from uos import *  # noqa\n\n\ndef urandom(n):\n    return bytes(n)\n")
    env = firmware_env(stim, board_opts=opts)
    env["MICROPYPATH"] = f"{shim}:{BOARD}:{FIRMWARE}"
    proc = subprocess.run([tool("micropython"), "-X", f"heapsize={heap}", str(BOARD / "run_firmware.py"),
                           str(cfg.rate_hz), str(cfg.batch), str(cfg.ring_size or 0)],
                          capture_output=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")[-2000:]
    return proc.stdout


CASES = {
    # the RP2040's DMA scan (conversions taken in pieces that a 3-row window must split), four halls
    "pico_dma": (dict(seed=11, wheel_speeds=True, rate_hz=1000), {}),
    # the ESP32's read_uv, a host stall
    "esp32": (dict(seed=12, board="esp32", stalls=((1.5, 0.3),)), {}),
    # a Pico without DMA or PIO: machine.ADC.read_u16 at the sample instants, the tick wrap
    "pico_plain": (dict(seed=13, start_ticks=(1 << 30) - 1_000_000), {"rp2_dma": False, "rp2_pio": False}),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_firmware_bytes_do_not_depend_on_the_window(tmp_path, name):
    kw, opts = CASES[name]
    cfg = SimConfig(plan=Plan(duration=1.5, still=0.5, run_up=1.0, speed_profile="track"), **kw)
    stim = tmp_path / "stim.bin"
    write_stimulus(cfg, stim)
    whole = _firmware_bytes(stim, tmp_path, cfg, dict(opts, stim_rows=WHOLE))
    for rows in (3, 50):
        assert _firmware_bytes(stim, tmp_path, cfg, dict(opts, stim_rows=rows)) == whole, rows
    frames = FrameDecoder().feed(whole)
    assert sum(1 for f in frames if f.type in p.SAMPLE_TYPES) > 50  # the comparison is of a real stream


def test_a_stimulus_larger_than_the_heap_runs(tmp_path):
    # 7 MB of voltage rows (3 s at 400 kHz) under a 2 MB heap: a board holding the file fails
    # with MemoryError. The samples' ay counts follow the stimulus's 0.7 Hz sine.
    stim = tmp_path / "big.bin"
    fs = 400_000
    st = simple_stimulus(stim, seconds=3.0, fs=fs)
    assert stim.stat().st_size > 7e6
    cfg = SimConfig()
    out = _firmware_bytes(stim, tmp_path, cfg, {}, heap="2M")
    frames = FrameDecoder().feed(out)
    s = p.samples_from_records((f.version, f.type, f.samples_bytes()) for f in frames if f.type in p.SAMPLE_TYPES)
    assert len(s) > 0.9 * 3.0 * cfg.rate_hz
    # the pin's voltage at each sample's instant (27 is ay on the Pico), in 12-bit counts
    t_us = s["t_us"].astype(np.int64)
    volts = st.volts[27][np.minimum(t_us * fs // 1_000_000, len(st.volts[27]) - 1)]
    expected = np.round(volts / 3.3 * 4095)
    assert np.max(np.abs(s["ay"].astype(np.int64) - expected)) <= 2  # 0.4 V over 0.7 Hz: < 1 count per 10 us
