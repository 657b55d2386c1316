# Sample ring buffer between the sampler interrupt (producer) and the main loop
# (consumer). Only the producer writes `head`, only the consumer writes `tail`,
# so no lock is needed. A full ring drops the new sample and counts it: the
# sampler never waits for a slow host.
import struct
from array import array
from micropython import const

from codec import SAMPLE_SIZE, SAMPLE_FMT, copy_bytes

_MASK30 = const(0x3FFFFFFF)


class SampleRing:
    def __init__(self, size):
        self.size = size
        self.buf = bytearray(size * SAMPLE_SIZE)
        self.index = array("i", [0] * size)  # sample index held by each slot
        self.head = 0  # slots written, mod 2^30
        self.tail = 0  # slots read, mod 2^30
        self.overruns = 0
        self.peak = 0

    def fill(self):
        return (self.head - self.tail) & _MASK30

    def push(self, index, t_us, ax, ay, az, yaw, steer_us, wheel_count, wheel_t_us, vbat):
        # Called from the sampler interrupt: no allocation, no floats.
        fill = (self.head - self.tail) & _MASK30
        if fill >= self.size:
            self.overruns += 1
            return
        slot = self.head % self.size
        struct.pack_into(SAMPLE_FMT, self.buf, slot * SAMPLE_SIZE, t_us, ax, ay, az, yaw,
                         steer_us, wheel_count, wheel_t_us, vbat)
        self.index[slot] = index
        self.head = (self.head + 1) & _MASK30
        if fill + 1 > self.peak:
            self.peak = fill + 1

    def run_length(self, limit):
        # How many of the oldest samples (at most `limit`) have consecutive indices;
        # a frame must not span a gap left by an overrun.
        fill = (self.head - self.tail) & _MASK30
        if fill > limit:
            fill = limit
        if fill == 0:
            return 0
        slot = self.tail % self.size
        first = self.index[slot]
        n = 1
        while n < fill:
            slot += 1
            if slot == self.size:
                slot = 0
            if self.index[slot] != (first + n) & _MASK30:
                break
            n += 1
        return n

    def first_index(self):
        return self.index[self.tail % self.size]

    def pop_into(self, dst, offset, n):
        # Copy the n oldest records to dst[offset:], then release them.
        slot = self.tail % self.size
        first = self.size - slot
        if first > n:
            first = n
        copy_bytes(dst, offset, self.buf, slot * SAMPLE_SIZE, first * SAMPLE_SIZE)
        if n > first:
            copy_bytes(dst, offset + first * SAMPLE_SIZE, self.buf, 0, (n - first) * SAMPLE_SIZE)
        self.tail = (self.tail + n) & _MASK30
