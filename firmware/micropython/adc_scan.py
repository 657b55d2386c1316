# RP2040 analog channels sampled by the hardware, not by the interrupt.
#
# The ADC free-runs round robin over the sensor channels (RP2040 datasheet 4.9:
# CS.RROBIN, CS.START_MANY), one conversion every DIV-set interval of its own
# 48 MHz clock; a DMA channel paced by the ADC's DREQ moves each result from the
# FIFO (FCS.EN, FCS.DREQ_EN) into a ring in RAM, wrapping in hardware (DMA
# ring_size). So every channel is converted at an exact instant, a scan of all of
# them takes `scan_us` (a few us: the channels are `scan_us / n` apart), and the
# timer interrupt only picks, for its period, the scan that ended just before the
# period's nominal instant. Its time is known from the scan number alone -- no
# interrupt latency in it. A second DMA channel, chained, re-arms the first when
# its transfer count runs out, so the scan never stops.
#
# The ADC clock (48 MHz from PLL_USB) and ticks_us (clk_ref) come from the same
# crystal: scan numbers and ticks do not drift apart. The offset between them is
# measured once at start (`t0`, to a few us: the time of the Python statements
# around START_MANY).
#
# Hot path (latch, the readers): no allocation, every integer < 2^30 (RAM
# addresses on the RP2040 are 0x2000_0000..0x2004_2000); ticks are combined by
# time.ticks_add / ticks_diff only.
import time

import uctypes
from machine import mem32
from micropython import const

from codec import add30

# RP2040 ADC registers (datasheet 4.9.6); above 2^30, so plain ints (big on the chip),
# used only to start and stop
_CS = 0x4004C000
_FCS = 0x4004C008
_FIFO = 0x4004C00C
_DIV = 0x4004C010
_CS_EN = const(1)
_CS_START_MANY = const(8)
_CS_READY = const(0x100)
_FCS_EN = const(1)
_FCS_DREQ_EN = const(8)
_FCS_OVER_UNDER = const(0xC00)  # write 1 to clear
_DREQ_ADC = const(36)  # RP2040 (RP2350: 48, and another ADC base: not supported here)
_RING_BITS = const(12)  # 4096-byte ring: 512 scans of 4 channels
_FILLER_AIN = const(4)  # the temperature sensor input: pads a 3-channel scan to 4 (no pin)
_COUNT = const(0x3FFFFFFF)  # transfers per DMA run (35 min at 2 us); the chain re-arms it
_TRANS_COUNT_TRIG = const(7)  # DMA channel register AL1_TRANS_COUNT_TRIG (offset 0x1C) / 4


def scan_us_for(period_us):
    """Scan length [us] for a sample period: the smallest divisor of the period
    that gives each of the 4 conversions >= 2 us (the ADC's 96 cycles at 48 MHz),
    so every period holds a whole number of scans. Periods are divisors of 10^6
    (2^a 5^b), so this is 8 or 10 us (25 for odd periods)."""
    s = 8
    while period_us % s:
        s += 1
    return s


def unavailable():
    """Why the hardware scan cannot run here (None: it can). Only for a board whose
    profile has an RP2040 (`adc_scan`)."""
    import sys
    if "RP2350" in getattr(sys.implementation, "_machine", ""):
        return "RP2350: other DREQ numbers and ADC registers"
    try:
        import rp2
        rp2.DMA  # noqa: B018  (in rp2 since MicroPython 1.22)
    except (ImportError, AttributeError):
        return "no rp2.DMA (MicroPython < 1.22)"
    return None


class AdcScan:
    def __init__(self, ain_list, period_us):
        # ain_list: ADC input (0..3) of each channel, in the order of readers()
        import rp2
        if len(ain_list) > 3 or len(set(ain_list)) != len(ain_list):
            raise ValueError("the scan takes 1..3 distinct ADC inputs")
        order = sorted(ain_list) + [_FILLER_AIN]
        while len(order) < 4:  # a power of two of 2-byte results per scan: the ring wraps on scans
            order.insert(-1, [a for a in (0, 1, 2, 3) if a not in order][0])
        self.order = order
        self.slot_of = [order.index(a) for a in ain_list]
        self.scan_us = scan_us_for(period_us)
        self.per_period = period_us // self.scan_us
        self.period_us = period_us
        self.scans = (1 << _RING_BITS) // 8
        # the DMA ring must be aligned to its size: take an aligned window of twice that
        raw = bytearray(2 << _RING_BITS)
        a = uctypes.addressof(raw)
        skip = (-a) & ((1 << _RING_BITS) - 1)
        self._raw = raw
        self.buf = memoryview(raw)[skip:skip + (1 << _RING_BITS)]
        self.base = a + skip
        self.cur = 0  # byte offset of the latched scan in buf
        self.t0 = 0  # ticks of scan 0's first conversion
        self._slot = 0  # ring slot (scan number mod scans) of the next period's scan
        self._t = 0  # ticks of that scan
        self.late_scans = 0  # periods whose scan was overwritten: the newest was taken instead
        self.late_us = 0  # how far the latched scan is behind the period's own (0 but for those)
        self._dma = rp2.DMA()
        self._reload = rp2.DMA()
        self._count = bytearray(4)
        self._count[0] = _COUNT & 0xFF
        self._count[1] = (_COUNT >> 8) & 0xFF
        self._count[2] = (_COUNT >> 16) & 0xFF
        self._count[3] = _COUNT >> 24

    def readers(self):
        """One zero-argument function per channel: its value in the latched scan, 12-bit."""
        out = []
        for k in self.slot_of:
            out.append(self._reader(2 * k))
        return out

    def _reader(self, off):
        buf = self.buf
        scan = self

        def read():
            i = scan.cur + off
            return (buf[i] | (buf[i + 1] << 8)) & 0xFFF

        return read

    def start(self, t_first_nominal, ticks_us):
        """Start the ADC and the DMA; the first period's nominal instant is t_first_nominal."""
        self._dma.active(0)
        mem32[_CS] = _CS_EN  # stop a running scan (ADC(Pin) objects have set the pads and EN)
        while not mem32[_CS] & _CS_READY:  # a conversion under way would land after the drain
            pass
        while mem32[_FCS] & 0xF0000:  # drain the FIFO (LEVEL)
            mem32[_FIFO]
        mem32[_FCS] = _FCS_EN | _FCS_DREQ_EN | (1 << 24) | _FCS_OVER_UNDER  # DREQ at >= 1 result
        mem32[_DIV] = (12 * self.scan_us - 1) << 8  # 4 conversions of 12*scan_us cycles at 48 MHz
        d = self._dma
        r = self._reload
        ctrl = d.pack_ctrl(size=1, inc_read=False, inc_write=True, ring_sel=True, ring_size=_RING_BITS,
                           treq_sel=_DREQ_ADC, chain_to=r.channel, irq_quiet=True)
        d.config(read=_FIFO, write=self.buf, count=_COUNT, ctrl=ctrl, trigger=True)
        trig = uctypes.addressof(d.registers) + 4 * _TRANS_COUNT_TRIG
        rc = r.pack_ctrl(size=2, inc_read=False, inc_write=False, irq_quiet=True)
        r.config(read=self._count, write=trig, count=1, ctrl=rc, trigger=False)
        rr = 0
        for a in self.order:
            rr |= 1 << a
        cs = _CS_EN | (rr << 16) | (self.order[0] << 12)
        t_a = ticks_us()
        mem32[_CS] = cs | _CS_START_MANY
        t_b = ticks_us()
        self.t0 = time.ticks_add(t_a, time.ticks_diff(t_b, t_a) >> 1)
        # the scan for a period is the one that ends at least one scan before its nominal
        # instant (one scan of margin for the few us t0 is uncertain)
        k = time.ticks_diff(t_first_nominal, self.t0) // self.scan_us - 2
        self._slot = k & (self.scans - 1)
        self._t = time.ticks_add(self.t0, k * self.scan_us)

    def stop(self):
        mem32[_CS] = _CS_EN
        self._dma.active(0)

    def skip(self, periods):
        # periods with no sample (a soft timer's lost ticks): their scans are passed by
        # (periods - 1) * period is < 2^29 (the sampler's lost span), periods * period may not
        # be: ticks_add takes |delta| < 2^29 only
        self._slot = (self._slot + periods * self.per_period) & (self.scans - 1)
        self._t = time.ticks_add(time.ticks_add(self._t, (periods - 1) * self.period_us), self.period_us)

    def latch(self, now):
        """Latch the scan of the current period (readers() read it); return its ticks.
        now: ticks when the interrupt runs. Then step to the next period's scan."""
        t = self._t
        slot = self._slot
        self.late_us = 0
        age = time.ticks_diff(now, t)
        age = age // self.scan_us if age > 0 else 0  # scans since this one began
        if age >= self.scans - 4:  # overwritten (a soft timer ran very late): take the newest
            written = ((self._dma.write - self.base) >> 3) & (self.scans - 1)  # scan being filled
            back = (written - slot) & (self.scans - 1)
            laps = (age - back + (self.scans >> 1)) // self.scans
            newest = back + laps * self.scans - 1
            slot = (written - 1) & (self.scans - 1)
            t = time.ticks_add(t, newest * self.scan_us)
            self.late_us = newest * self.scan_us
            self.late_scans += 1
        self.cur = slot << 3
        self._slot = (self._slot + self.per_period) & (self.scans - 1)
        self._t = time.ticks_add(self._t, self.period_us)
        return t
