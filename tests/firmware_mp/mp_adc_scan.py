# The RP2040 hardware scan on the simulated board: each latched scan holds the values
# the ADC converted at the scan's stamped instant; the chained DMA channel re-arms the
# ring's channel when its count runs out (shortened here from 2^30 - 1 transfers);
# a scan overwritten before a very late call is replaced by the newest, with its time.
# usage: micropython mp_adc_scan.py   (hil_sim/board first on MICROPYPATH)
import struct
import time

import app
import simboard
from mptest import check, done

M30 = 0x3FFFFFFF
b = simboard.board()
s = b.stim


class Sink:
    def write(self, buf, n=-1):
        return len(buf) if n < 0 else n


def expected(pin, t_ticks):
    # the RP2040 count of the stimulus at that instant (12 bits over 0..3.3 V)
    t = (t_ticks - b.start_ticks) & M30
    a = t * s.fs
    row = a // 1000000
    v0 = s.volt(row, s.cols[pin])
    v1 = s.volt(row + 1, s.cols[pin])
    # the signal between stimulus rows, in 1e-6 of 0.1 mV, rounded once by the converter
    v = v0 * 1000000 + (v1 - v0) * (a % 1000000)
    c = (v * 4095 + 16500000000) // 33000000000
    return 4095 if c > 4095 else c


fw = app.App(board="pico", rate_hz=500, batch=10, ring_size=64, out=Sink())
fw.start()
scan = fw.scan
check(scan is not None, "the hardware scan runs")
check(fw.hello["capture"]["adc"] == "dma", "HELLO says so")
ax, ay, yaw = scan.readers()
struct.pack_into("<I", scan._count, 0, 3000)  # the reload value the chained channel writes
scan._dma.remaining = 1000  # the running transfer ends after 1000 more conversions
bad = 0
checked = 0
runs = fw.sampler.runs
while b.now < 2000000:  # 2 s of the 3 s stimulus
    b.idle()
    fw.pump()
    fw.service()
    if fw.sampler.runs != runs:
        runs = fw.sampler.runs
        t = (scan._t - scan.period_us) & M30  # instant of the scan just latched
        st = scan.scan_us // 4
        if (ax(), ay(), yaw()) != (expected(26, t), expected(27, t + st), expected(28, t + 2 * st)):
            bad += 1
        checked += 1
check(checked > 800, "scans checked (%d)" % checked)
check(bad == 0, "every scan holds the stimulus at its instants (%d wrong)" % bad)
check(b.rp2040.reloads >= 3, "the chained DMA channel re-armed the ring (%d times)" % b.rp2040.reloads)
check(not b.rp2040.adc.fcs & 0x800, "the ADC FIFO never overflowed")

# the model refuses what would break the round robin on the chip
from machine import ADC, Pin  # noqa: E402

try:
    ADC(Pin(26)).read_u16()
    refused = False
except Exception as e:  # rp2040_hw.HwError
    refused = "round robin" in str(e)
check(refused, "ADC.read_u16 while the scan runs is refused")

# a call 10 ms late: its scan (4 ms of ring) is gone; the newest complete one is taken
fw._timer.deinit()
b.advance_to(b.now + 10000)
now = time.ticks_us()
t = scan.latch(now)
age = (now - t) & M30
check(scan.late_us > 0 and scan.late_scans == 1, "the overwritten scan is reported late")
check(scan.scan_us <= age <= 3 * scan.scan_us, "the newest complete scan is taken (%d us old)" % age)
check(ax() == expected(26, t) and yaw() == expected(28, t + 2 * (scan.scan_us // 4)),
      "its values are the stimulus at its stamped instant")
done()
