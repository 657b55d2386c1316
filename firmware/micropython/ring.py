# Sample ring buffer between the sampler interrupt (producer) and the main loop
# (consumer). Only the producer writes `head`, only the consumer writes `tail`,
# so no lock is needed. A full ring drops the new sample and counts it: the
# sampler never waits for a slow host. The consumer copies records out (copy_into)
# and releases them only once they are gone whole (release): a write the host did
# not take leaves them in the ring, to be sent again.
#
# The producer packs a record straight into the ring: claim() gives the byte
# offset of the next free slot (or -1 when full), the caller packs the record
# there with struct.pack_into, and commit() publishes it.
import struct
from array import array
from micropython import const

from codec import SAMPLE_SIZE, SAMPLE_FMT, add30, copy_bytes

_MASK30 = const(0x3FFFFFFF)


class SampleRing:
    def __init__(self, size, record_size=SAMPLE_SIZE):
        self.size = size
        self.record_size = record_size
        self.buf = bytearray(size * record_size)
        self.index = array("i", [0] * size)  # sample index held by each slot
        self.head = 0  # slots written, mod 2^30
        self.tail = 0  # slots read, mod 2^30
        self.overruns = 0
        self.peak = 0

    def fill(self):
        return (self.head - self.tail) & _MASK30

    def claim(self, index):
        # Called from the sampler interrupt: no allocation, no floats. Returns the
        # offset in buf where the record of sample `index` goes, or -1 (dropped).
        fill = (self.head - self.tail) & _MASK30
        if fill >= self.size:
            self.overruns = add30(self.overruns, 1)
            return -1
        slot = self.head % self.size
        self.index[slot] = index
        if fill + 1 > self.peak:
            self.peak = fill + 1
        return slot * self.record_size

    def commit(self):
        self.head = add30(self.head, 1)

    def push(self, index, t_us, ax, ay, az, yaw, steer_us, wheel_count, wheel_t_us, vbat, steer_t_us):
        # A one-wheel record in one call (tests and simple callers).
        off = self.claim(index)
        if off >= 0:
            struct.pack_into(SAMPLE_FMT, self.buf, off, t_us, ax, ay, az, yaw, steer_us,
                             wheel_count, wheel_t_us, vbat, steer_t_us)
            self.commit()

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
            if self.index[slot] != add30(first, n):
                break
            n += 1
        return n

    def first_index(self):
        return self.index[self.tail % self.size]

    def copy_into(self, dst, offset, n):
        # Copy the n oldest records to dst[offset:]; they stay in the ring (release).
        rs = self.record_size
        slot = self.tail % self.size
        first = self.size - slot
        if first > n:
            first = n
        copy_bytes(dst, offset, self.buf, slot * rs, first * rs)
        if n > first:
            copy_bytes(dst, offset + first * rs, self.buf, 0, (n - first) * rs)

    def release(self, n):
        # The n oldest records have left: their slots are free.
        self.tail = add30(self.tail, n)
