"""Link faults between the firmware and the port: bit errors, dropped and
inserted bytes. Every byte of the clean stream that a fault touched is recorded,
so a test can tell which frames arrived intact."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LinkFaults:
    ber: float = 0.0  # bit error rate
    drop_rate: float = 0.0  # per byte
    insert_rate: float = 0.0  # per byte: 1-3 random bytes inserted before it
    seed: int = 0
    touched: list = field(default_factory=list)  # offsets in the clean stream
    offset: int = 0
    _rng: np.random.Generator | None = None

    @property
    def active(self) -> bool:
        return self.ber > 0 or self.drop_rate > 0 or self.insert_rate > 0

    def apply(self, data: bytes) -> bytes:
        n = len(data)
        base = self.offset
        self.offset += n
        if not self.active or n == 0:
            return data
        rng = self._rng = self._rng or np.random.default_rng(self.seed + 7919)
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        bits = rng.integers(0, 8 * n, rng.binomial(8 * n, self.ber)) if self.ber else np.zeros(0, int)
        np.bitwise_xor.at(buf, bits // 8, (1 << (bits % 8)).astype(np.uint8))
        drop = rng.random(n) < self.drop_rate if self.drop_rate else np.zeros(n, bool)
        ins = np.flatnonzero(rng.random(n) < self.insert_rate) if self.insert_rate else np.zeros(0, int)
        hit = set((bits // 8).tolist()) | set(np.flatnonzero(drop).tolist()) | set(ins.tolist())
        self.touched.extend(sorted(base + i for i in hit))
        if not len(ins):
            return buf[~drop].tobytes()
        pieces, start = [], 0
        for i in ins:
            pieces.append(buf[start:i][~drop[start:i]])
            pieces.append(rng.integers(0, 256, int(rng.integers(1, 4)), dtype=np.uint8))
            start = i
        pieces.append(buf[start:][~drop[start:]])
        return np.concatenate(pieces).tobytes()
