# The timer-driven sampler: one interrupt per sample reads every channel into
# the ring buffer. It is the hot path: no allocation, no floats, no formatting.
# Each record is packed straight into its ring slot (struct.pack_into).
import struct
import time
from micropython import const

from codec import SAMPLE_FMT, SAMPLE_SIZE, WHEELS3_FMT

_MASK30 = const(0x3FFFFFFF)


class Sampler:
    def __init__(self, ring, readers, steer, wheels):
        # wheels: one or four HallCounter objects, in record order
        self.ring = ring
        self._ax, self._ay, self._az, self._yaw, self._vbat = readers
        self._steer = steer
        self._w0 = wheels[0]
        self._four = len(wheels) == 4
        self._w1 = self._w2 = self._w3 = None
        if self._four:
            self._w1, self._w2, self._w3 = wheels[1], wheels[2], wheels[3]
        self.index = 0  # samples taken since boot, mod 2^30 (dropped ones included)
        self.isr_last_us = 0
        self.isr_max_us = 0

    def isr(self, _timer):
        t = time.ticks_us() & _MASK30
        ring = self.ring
        off = ring.claim(self.index)
        if off >= 0:
            st = self._steer
            w = self._w0
            # steer_us and steer_t_us: width and falling-edge time of the same pulse
            # (read() takes them together and leaves the edge time in t_read)
            struct.pack_into(SAMPLE_FMT, ring.buf, off, t, self._ax(), self._ay(), self._az(), self._yaw(),
                             st.read(t), w.count, w.t_last, self._vbat(), st.t_read)
            if self._four:
                a = self._w1
                b = self._w2
                c = self._w3
                struct.pack_into(WHEELS3_FMT, ring.buf, off + SAMPLE_SIZE, a.count, a.t_last,
                                 b.count, b.t_last, c.count, c.t_last)
            ring.commit()
        self.index = (self.index + 1) & _MASK30
        d = time.ticks_diff(time.ticks_us(), t)
        self.isr_last_us = d
        if d > self.isr_max_us:
            self.isr_max_us = d
