# Pulse inputs on the simulated board's clock (ticks wrap at 2^30 as on a board).
# usage: micropython mp_pulses.py   (hil_sim/board first on MICROPYPATH)
import time

import simboard
from mptest import check, done
from pulses import HallCounter, ServoPulse

b = simboard.board()
PIN = 40


def edge(obj, t, level):
    b.now = t
    b.pin_level[PIN] = level
    obj._edge(obj.pin)


# -- steering: a pulse, then the receiver is lost for 18 minutes -------------------
sp = ServoPulse(PIN, 100000)
t0 = 5000000
edge(sp, t0, 1)
edge(sp, t0 + 1500, 0)
b.now = t0 + 2000
check(sp.read(time.ticks_us()) == 1500, "pulse width read")
check(sp.t_read == (t0 + 1500) & 0x3FFFFFFF, "falling edge time")
bad = 0
first_bad = -1
step = 2000  # the sampler reads every period (500 Hz)
t = t0 + 2000
end = t0 + 18 * 60 * 1000000
while t < end:
    t += step * 50  # every 50th sample is enough to see an alias (it lasts ~8 min)
    b.now = t
    w = sp.read(time.ticks_us())
    if t - (t0 + 1500) > 100000 and w != 0:
        bad += 1
        if first_bad < 0:
            first_bad = t - t0
check(bad == 0, "no pulse comes back after the receiver is lost (first at %d s)" % (first_bad // 1000000))
edge(sp, end + 10, 1)
edge(sp, end + 10 + 1200, 0)
b.now = end + 2000
check(sp.read(time.ticks_us()) == 1200, "a new pulse is read again")

# -- hall: a bounce 30 us after an edge is not a pulse -----------------------------
PIN = 41
hc = HallCounter(PIN, 200)
for k in range(5):
    t = 9000000 + k * 10000
    edge(hc, t, 0)
    edge(hc, t + 30, 0)  # contact bounce / ringing
check(hc.count == 5, "five edges counted, bounces ignored (%d)" % hc.count)
check(hc.bounces == 5, "five bounces seen")
check(hc.t_last == (9000000 + 40000) & 0x3FFFFFFF, "edge time is the real edge's")

# -- as of a sample instant before the interrupt (adc_scan): later edges not yet ----------
t_s = (9000000 + 40000 - 10) & 0x3FFFFFFF  # 10 us before the last edge
hc.snap(t_s, True)
check(hc.s_count == 4 and hc.s_t == (9000000 + 30000) & 0x3FFFFFFF, "hall as of an earlier instant")
hc.snap(t_s, False)
check(hc.s_count == 5, "hall as of the interrupt")
PIN = 40
edge(sp, end + 30000, 1)
edge(sp, end + 30000 + 1700, 0)
b.now = end + 30000 + 1720
t_s = (end + 30000 + 1690) & 0x3FFFFFFF  # before the fall of the 1700 us pulse
check(sp.read(time.ticks_us(), t_s) == 1200 and sp.t_read == (end + 10 + 1200) & 0x3FFFFFFF,
      "servo as of an earlier instant: the pulse before")
check(sp.read(time.ticks_us()) == 1700, "servo as of the interrupt: the latest")
done()
