# The timer-driven sampler: one interrupt per sample reads every channel into
# the ring buffer. It is the hot path: no allocation, no floats, no formatting.
# Each record is packed straight into its ring slot (struct.pack_into).
#
# Every timer period gets an index. Where the timer is soft (ESP32; rp2 before
# MicroPython 1.26) the callback is only scheduled: it runs late when the main
# loop is inside a blocking write, and a tick that finds the 8-deep scheduler
# queue full is lost. Queued calls run in tick order, so each call belongs to the
# oldest tick not yet served -- unless that tick fired before `t_free`, the last
# moment the main loop ran bytecode (set just before each write): scheduled
# callbacks run at every bytecode boundary, so a tick that old was lost, not
# queued. Lost ticks advance the index and are counted in `missed`: the host sees
# a gap, never a stretched clock. `late_max_us` is how far behind its tick's
# nominal instant (start + index * period) a sample was taken.
#
# With a hardware scan (adc_scan.py, RP2040) the analog values were converted by
# the ADC at an instant fixed by its own clock: the interrupt only latches that
# period's scan, and the record's time is the scan's, not the interrupt's. The
# lateness is then the scan's (0 unless a very late soft call found it overwritten).
#
# Ticks are combined only by time.ticks_add / ticks_diff, counters wrap by add30:
# on a board a small int holds 31 bits, and an intermediate >= 2^30 (t + period
# before a mask) is a heap object -- in a hard interrupt, a MemoryError that stops
# the timer for good (rp2).
import struct
import time
from micropython import const

from codec import SAMPLE_FMT, SAMPLE_SIZE, WHEELS3_FMT, add30

_FREE_MARGIN_US = const(200)  # a tick this close before t_free may still be queued


class Sampler:
    def __init__(self, ring, readers, steer, wheels, period_us, scan=None):
        # wheels: one or four HallCounter objects, in record order
        # scan: an AdcScan whose readers are in `readers` (None: readers convert themselves)
        self._scan = scan
        self.ring = ring
        self._ax, self._ay, self._az, self._yaw, self._vbat = readers
        self._steer = steer
        self._w0 = wheels[0]
        self._four = len(wheels) == 4
        self._w1 = self._w2 = self._w3 = None
        if self._four:
            self._w1, self._w2, self._w3 = wheels[1], wheels[2], wheels[3]
        self.period_us = period_us
        self.index = 0  # timer periods since start, mod 2^30 (dropped and missed ones included)
        self.runs = 0  # calls that took a sample: the watchdog is fed only while this moves
        self.missed = 0  # periods in which no call came (soft timer queue full or late)
        self.late_max_us = 0
        self._t_next = -1  # ticks of the nominal instant of `index`; -1 before the first call
        self.t_free = 0  # ticks when the main loop last ran bytecode before a blocking write
        self.isr_last_us = 0
        self.isr_max_us = 0

    def arm(self, t_start):
        # The timer was started at t_start: its first tick is due one period later.
        self._t_next = time.ticks_add(t_start, self.period_us)
        if self._scan is not None:
            self._scan.start(self._t_next, time.ticks_us)

    def isr(self, _timer):
        t = time.ticks_us()
        t_isr = t
        if self._t_next < 0:
            self._t_next = t
        old = time.ticks_diff(self.t_free, self._t_next) - _FREE_MARGIN_US
        if old >= 0 and time.ticks_diff(t, self.t_free) >= 0:  # ticks up to t_free were lost
            # k whole periods were lost. ticks_add takes |delta| < 2^29 only (extmod/modtime.c:
            # OverflowError) and k * period reaches old + period, past 2^29 after ~9 min of lost
            # ticks: step by the whole periods in `old` (< 2^29), then by one period
            whole = old - old % self.period_us
            k = whole // self.period_us + 1
            self.index = add30(self.index, k)
            self.missed = add30(self.missed, k)
            self._t_next = time.ticks_add(time.ticks_add(self._t_next, whole), self.period_us)
            if self._scan is not None:
                self._scan.skip(k)
        late = time.ticks_diff(t, self._t_next)
        if late < 0:  # the timer runs a little fast against our grid: follow it
            self._t_next = t
            late = 0
        if self._scan is not None:
            t = self._scan.latch(t)  # the scan's own instant: no interrupt latency in it
            late = self._scan.late_us
        if late > self.late_max_us:
            self.late_max_us = late
        ring = self.ring
        off = ring.claim(self.index)
        if off >= 0:
            st = self._steer
            w = self._w0
            # with a scan, t is before the interrupt: pulses and edges as of t, like the
            # analog values (an edge at t itself comes after, as a timer fired first)
            scan = self._scan is not None
            w.snap(t, scan)
            # steer_us and steer_t_us: width and falling-edge time of the same pulse
            # (read() takes them together and leaves the edge time in t_read)
            struct.pack_into(SAMPLE_FMT, ring.buf, off, t, self._ax(), self._ay(), self._az(), self._yaw(),
                             st.read(t, t if scan else -1), w.s_count, w.s_t, self._vbat(), st.t_read)
            if self._four:
                a = self._w1
                b = self._w2
                c = self._w3
                a.snap(t, scan)
                b.snap(t, scan)
                c.snap(t, scan)
                struct.pack_into(WHEELS3_FMT, ring.buf, off + SAMPLE_SIZE, a.s_count, a.s_t,
                                 b.s_count, b.s_t, c.s_count, c.s_t)
            ring.commit()
        self.index = add30(self.index, 1)
        self._t_next = time.ticks_add(self._t_next, self.period_us)
        self.runs = add30(self.runs, 1)
        d = time.ticks_diff(time.ticks_us(), t_isr)
        self.isr_last_us = d
        if d > self.isr_max_us:
            self.isr_max_us = d
