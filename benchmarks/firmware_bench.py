"""Firmware hot path under the MicroPython unix port, and an estimate for the RP2040."""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from hil_sim.firmware_runner import BOARD_DIR, FIRMWARE_DIR, micropython_exe
from hil_sim.stimulus import Stimulus

HERE = Path(__file__).resolve().parent
# A bare `while i < n: i += 1` loop runs at ~1.0 M iterations/s on an RP2040 at
# 125 MHz with MicroPython (bytecode; order of magnitude from public benchmarks,
# not measured here). We measure the same loop on this PC and scale the hot path
# by the ratio; the ADC conversions (~2 us each on the RP2040) are added on top
# because the simulated board's ADC is a table lookup.
RP2040_LOOP_PER_S = 1.0e6
RP2040_ADC_US = 2.0
ADC_READS = 3  # Pico: ax, ay, yaw


def hot_path(quick: bool) -> dict:
    n = 20_000 if quick else 200_000
    with tempfile.TemporaryDirectory() as d:
        stim = Path(d) / "stim.bin"
        fs = 5000
        t = np.arange(fs * 400) / fs
        Stimulus(board="pico", fs_sig=fs, volts={26: 1.65 + 0 * t, 27: 1.7 + 0 * t, 28: 1.6 + 0 * t},
                 steer_us=np.full(20000, 1500), hall_t_us=np.arange(10_000, 399_000_000, 30_000),
                 steer_pin=2, hall_pin=3).write(stim)
        env = dict(os.environ, MICROPYPATH=f"{BOARD_DIR}:{FIRMWARE_DIR}", STID_SIM_STIMULUS=str(stim))
        out = subprocess.run([micropython_exe(), "-X", "heapsize=64M", str(HERE / "mp_hotpath.py"), str(n)],
                             capture_output=True, text=True, env=env, check=True).stdout
    r = json.loads(out.strip().splitlines()[-1])
    pc_loop_per_s = 1e6 / (r["loop_1e6_us"] * 1e-6)
    scale = pc_loop_per_s / RP2040_LOOP_PER_S
    per_sample_pc = r["isr_us_per_sample"] + r["framing_us_per_sample"]
    per_sample_rp2040 = per_sample_pc * scale + ADC_READS * RP2040_ADC_US
    return {"isr_us": r["isr_us_per_sample"], "framing_us": r["framing_us_per_sample"],
            "per_sample_us_pc": per_sample_pc, "allocations": 0, "pc_vs_rp2040": scale,
            "rp2040_us_per_sample_est": per_sample_rp2040,
            "rp2040_max_rate_50pct_idle_est": 0.5e6 / per_sample_rp2040}
