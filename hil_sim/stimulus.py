"""The stimulus file: what the simulated board's pins see.

hil_sim computes pin voltages on a fine grid, the steering servo pulse train and
the hall edges, and writes them for ``board/simboard.py`` (MicroPython) to play.
Layout (little-endian): ``b"STIDSIM2"``, u32 header length, JSON header, then
u16 voltages in 0.1 mV (rows at ``fs_sig``, one column per analog pin), u16 servo
pulse widths [us], u32 their rising-edge times [us] (the receiver's own clock),
u32 hall edge times [us] of all hall pins merged in time order, u8 the pin of each
hall edge.
"""

from __future__ import annotations

import json
import shutil
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAGIC = b"STIDSIM2"
VOLT_UNIT = 1e-4  # 0.1 mV per count


@dataclass
class Stimulus:
    board: str
    fs_sig: int  # rate of the voltage grid [Hz]
    volts: dict  # pin number -> voltage array [V] on the grid
    steer_us: np.ndarray  # one width per servo pulse [us]
    hall_t_us: np.ndarray  # hall edge times [us] (the one hall sensor)
    steer_pin: int
    hall_pin: int
    steer_period_us: int = 20000  # used only when steer_rise_us is None
    steer_phase_us: int = 3000
    steer_rise_us: np.ndarray | None = None  # rising-edge time of each pulse [us]
    wheel_halls: dict | None = None  # four halls instead of one: position -> (pin, edge times [us])
    wheel_ppr: int = 1  # hall pulses per wheel revolution (declared in HELLO)
    start_ticks: int = 0  # virtual ticks_us at t = 0 (set near 2^30 to test the wrap)
    stalls: list = field(default_factory=list)  # [(at_us, for_us)]: host stops reading
    timer_fault_us: int | None = None  # the sampler's hard timer callback fails once then (rp2 stops it)
    # a run generated block by block holds no voltages: its rows are in a file (VoltRows)
    volt_rows: "VoltRows | None" = None

    @property
    def n_rows(self) -> int:
        if self.volt_rows is not None:
            return self.volt_rows.n_rows
        return len(next(iter(self.volts.values())))

    @property
    def pins(self) -> list:
        return list(self.volt_rows.pins) if self.volt_rows is not None else sorted(self.volts)

    @property
    def duration_us(self) -> int:
        return int(self.n_rows * 1_000_000 // self.fs_sig)

    def rise_us(self) -> np.ndarray:
        """Rising-edge time [us] of every servo pulse."""
        if self.steer_rise_us is not None:
            return np.asarray(self.steer_rise_us, dtype=np.int64)
        k = np.arange(len(self.steer_us), dtype=np.int64)
        return self.steer_phase_us + k * self.steer_period_us

    def fall_us(self) -> np.ndarray:
        """Falling-edge time [us] of every servo pulse (when the servo takes its width)."""
        return self.rise_us() + np.asarray(self.steer_us, dtype=np.int64)

    def hall_events(self):
        """(times [us], pins) of every hall edge, merged in time order."""
        if self.wheel_halls is None:
            t = np.asarray(self.hall_t_us, dtype=np.int64)
            return t, np.full(len(t), self.hall_pin, dtype=np.int64)
        ts, ps = [], []
        for pin, edges in self.wheel_halls.values():
            ts.append(np.asarray(edges, dtype=np.int64))
            ps.append(np.full(len(edges), pin, dtype=np.int64))
        t, pins = np.concatenate(ts), np.concatenate(ps)
        order = np.argsort(t, kind="stable")
        return t[order], pins[order]

    def write(self, path: Path) -> None:
        pins = self.pins
        counts = None if self.volt_rows is not None else volt_counts(self.volts, pins)
        n_rows = self.n_rows
        hall_t, hall_p = self.hall_events()
        rise = self.rise_us()
        if len(rise) != len(self.steer_us):
            raise ValueError("one rising edge per servo pulse width")
        if len(rise) > 1 and np.any(np.diff(rise) <= np.asarray(self.steer_us)[:-1]):
            raise ValueError("servo pulses overlap")
        header = {
            "board": self.board, "fs_sig": self.fs_sig, "n_rows": int(n_rows),
            "cols": {str(p): i for i, p in enumerate(pins)},
            "n_steer": int(len(self.steer_us)), "steer_pin": self.steer_pin,
            "n_hall": int(len(hall_t)), "hall_pins": sorted(set(int(x) for x in hall_p)) or [self.hall_pin],
            "wheels": None if self.wheel_halls is None else {k: int(v[0]) for k, v in self.wheel_halls.items()},
            "wheel_ppr": int(self.wheel_ppr),
            "duration_us": self.duration_us, "start_ticks": self.start_ticks,
            "stalls": [list(map(int, s)) for s in self.stalls],
            "timer_fault_us": None if self.timer_fault_us is None else int(self.timer_fault_us),
        }
        hb = json.dumps(header).encode()
        with open(path, "wb") as f:
            f.write(MAGIC + struct.pack("<I", len(hb)) + hb)
            if counts is None:
                self.volt_rows.copy_to(f)
            else:
                f.write(counts.tobytes())
            f.write(np.asarray(self.steer_us, dtype="<u2").tobytes())
            f.write(rise.astype("<u4").tobytes())
            f.write(hall_t.astype("<u4").tobytes())
            f.write(hall_p.astype("u1").tobytes())

    def volts_counts(self, pin: int) -> np.ndarray:
        """The 0.1 mV values the board reads for ``pin`` (as written to the file)."""
        return np.clip(np.round(self.volts[pin] / VOLT_UNIT), 0, 65535).astype(np.int64)


def volt_counts(volts: dict, pins) -> np.ndarray:
    """The rows of the file's voltage block: one column per pin, in 0.1 mV counts."""
    grid = np.stack([volts[p] for p in pins], axis=1)
    return np.clip(np.round(grid / VOLT_UNIT), 0, 65535).astype("<u2")


class VoltRows:
    """The voltage block of a stimulus written as it is computed, block by block, into a
    file of its own: a long run never holds its voltage grid (5 kHz x pins) in memory.
    ``Stimulus.write`` copies it into place behind the header, which needs the run's
    edge counts and so can only be written at the end."""

    def __init__(self, path: Path, pins):
        self.path = Path(path)
        self.pins = tuple(sorted(pins))
        self.n_rows = 0
        self._f = open(self.path, "wb")

    def add(self, volts: dict) -> None:
        counts = volt_counts(volts, self.pins)
        self._f.write(counts.tobytes())
        self.n_rows += counts.shape[0]

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def copy_to(self, f) -> None:
        self.close()
        with open(self.path, "rb") as src:
            shutil.copyfileobj(src, f, 1 << 20)
