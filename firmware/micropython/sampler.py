# The timer-driven sampler: one interrupt per sample reads every channel into
# the ring buffer. It is the hot path: no allocation, no floats, no formatting.
import time
from micropython import const

_MASK30 = const(0x3FFFFFFF)


class Sampler:
    def __init__(self, ring, readers, steer, wheel):
        self.ring = ring
        self._ax, self._ay, self._az, self._yaw, self._vbat = readers
        self._steer = steer
        self._wheel = wheel
        self.index = 0  # samples taken since boot, mod 2^30 (dropped ones included)
        self.isr_last_us = 0
        self.isr_max_us = 0

    def isr(self, _timer):
        t = time.ticks_us()
        self.ring.push(self.index, t & _MASK30, self._ax(), self._ay(), self._az(), self._yaw(),
                       self._steer.read(t), self._wheel.count, self._wheel.t_last, self._vbat())
        self.index = (self.index + 1) & _MASK30
        d = time.ticks_diff(time.ticks_us(), t)
        self.isr_last_us = d
        if d > self.isr_max_us:
            self.isr_max_us = d
