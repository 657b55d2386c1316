"""The stimulus file: what the simulated board's pins see.

hil_sim computes pin voltages on a fine grid, the steering servo pulse train and
the hall edges, and writes them for ``board/simboard.py`` (MicroPython) to play.
Layout (little-endian): ``b"STIDSIM1"``, u32 header length, JSON header, then
u16 voltages in 0.1 mV (rows at ``fs_sig``, one column per analog pin), u16 servo
pulse widths [us] (one per servo period), u32 hall edge times [us].
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAGIC = b"STIDSIM1"
VOLT_UNIT = 1e-4  # 0.1 mV per count


@dataclass
class Stimulus:
    board: str
    fs_sig: int  # rate of the voltage grid [Hz]
    volts: dict  # pin number -> voltage array [V] on the grid
    steer_us: np.ndarray  # one pulse width per servo period [us]
    hall_t_us: np.ndarray  # hall edge times [us]
    steer_pin: int
    hall_pin: int
    steer_period_us: int = 20000
    steer_phase_us: int = 3000
    start_ticks: int = 0  # virtual ticks_us at t = 0 (set near 2^30 to test the wrap)
    stalls: list = field(default_factory=list)  # [(at_us, for_us)]: host stops reading

    @property
    def n_rows(self) -> int:
        return len(next(iter(self.volts.values())))

    @property
    def duration_us(self) -> int:
        return int(self.n_rows * 1_000_000 // self.fs_sig)

    def write(self, path: Path) -> None:
        pins = sorted(self.volts)
        grid = np.stack([self.volts[p] for p in pins], axis=1)
        counts = np.clip(np.round(grid / VOLT_UNIT), 0, 65535).astype("<u2")
        header = {
            "board": self.board, "fs_sig": self.fs_sig, "n_rows": int(grid.shape[0]),
            "cols": {str(p): i for i, p in enumerate(pins)},
            "n_steer": int(len(self.steer_us)), "steer_period_us": self.steer_period_us,
            "steer_phase_us": self.steer_phase_us, "steer_pin": self.steer_pin,
            "n_hall": int(len(self.hall_t_us)), "hall_pin": self.hall_pin,
            "duration_us": self.duration_us, "start_ticks": self.start_ticks,
            "stalls": [list(map(int, s)) for s in self.stalls],
        }
        hb = json.dumps(header).encode()
        with open(path, "wb") as f:
            f.write(MAGIC + struct.pack("<I", len(hb)) + hb)
            f.write(counts.tobytes())
            f.write(np.asarray(self.steer_us, dtype="<u2").tobytes())
            f.write(np.asarray(self.hall_t_us, dtype="<u4").tobytes())

    def volts_counts(self, pin: int) -> np.ndarray:
        """The 0.1 mV values the board reads for ``pin`` (as written to the file)."""
        return np.clip(np.round(self.volts[pin] / VOLT_UNIT), 0, 65535).astype(np.int64)
