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

# -- a stop of 9-18 min: ticks_diff over it is meaningless (only within 2^29 us) ----------
# hall: the sampler snaps every period (every 50th here); the next edge after the stop
# counts, and the count as of a sample instant never steps back while parked
PIN = 42
hc = HallCounter(PIN, 200)
t = 20000000
edge(hc, t, 0)
stop = 0
step_back = 0
for minutes in (10, 15):
    end_stop = t + minutes * 60 * 1000000
    while t < end_stop:
        t += 2000 * 50
        b.now = t
        hc.snap(time.ticks_us(), True)
        step_back += hc.s_count != hc.count
    edge(hc, t + 5, 0)
    t += 5
check(hc.count == 3, "edges after stops of 10 and 15 min are counted (%d of 3)" % hc.count)
check(step_back == 0, "the count as of a sample instant never stepped back while parked (%d)" % step_back)
# servo, as the Pico reads it (before = the sample's instant): stale for the whole outage
sp = ServoPulse(43, 50000)
PIN = 43
t = 30000000
edge(sp, t, 1)
edge(sp, t + 1500, 0)
edge(sp, t + 20000, 1)
edge(sp, t + 21600, 0)
bad = 0
t_end = t + 19 * 60 * 1000000
tt = t + 22000
while tt < t_end:
    b.now = tt
    now = time.ticks_us()
    w = sp.read(now, now - 10 if now >= 10 else 0)
    if tt - (t + 21600) > 50000 + 2000 * 50 and w != 0:
        bad += 1
    tt += 2000 * 50
check(bad == 0, "steer stays stale over a 19 min outage with before= (%d samples not)" % bad)
# a pulse after the outage, read before its fall: the one from before the outage never returns
edge(sp, t_end, 1)
edge(sp, t_end + 1200, 0)
b.now = t_end + 1210
now = time.ticks_us()
check(sp.read(now, now - 20) == 0, "the pulse before an outage is not the one in force after it")
check(sp.read(now, now) == 1200, "the new pulse is")


# -- an edge whose hard IRQ lands inside snap() (a Pico's soft sampler, MicroPython 1.23-1.25) --
class Racy(HallCounter):
    """The pin's IRQ runs once at a chosen point of snap(): at its first read of t_last after
    `between_reads` is set (between the reads of count and t_last), or when it marks the edge
    old after `before_old` is set (between its check of the edge's age and its write)."""

    def __init__(self, pin_no, debounce_us):
        self._tl = 0
        self._o = True
        self.between_reads = self.before_old = None
        super().__init__(pin_no, debounce_us)

    @property
    def t_last(self):
        t, self.between_reads = self.between_reads, None
        if t is not None:
            edge(self, t, 0)
        return self._tl

    @t_last.setter
    def t_last(self, v):
        self._tl = v

    @property
    def _old(self):
        return self._o

    @_old.setter
    def _old(self, v):
        t, self.before_old = (self.before_old, None) if v else (None, self.before_old)
        if t is not None:
            edge(self, t, 0)
        self._o = v


PIN = 44
hc = Racy(PIN, 200)
t = 40000000
edge(hc, t, 0)
hc.snap(t + 3000, False)
hc.between_reads = t + 5000
hc.snap(t + 5010, False)
check((hc.s_count, hc.s_t) in ((1, t & 0x3FFFFFFF), (2, (t + 5000) & 0x3FFFFFFF)),
      "count and edge time of one edge, an edge landing between their reads (%d, %d)" % (hc.s_count, hc.s_t))
hc.before_old = t + 10000  # the edge lands as the snap marks the one before old
hc.snap(t + 10000 + 10, False)
edge(hc, t + 10000 + 40, 0)  # that edge's bounce, 40 us on
check(hc.count == 3 and hc.bounces == 1, "the bounce of an edge that landed inside snap() is a bounce (%d pulses, "
      "%d bounces)" % (hc.count, hc.bounces))
done()
