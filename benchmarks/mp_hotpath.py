# MicroPython: time the firmware's hot path on the simulated board with the real
# clock (utime; `time` is the board's virtual clock). Prints JSON.
import json
import sys

import micropython
import utime

import app
import simboard


class Sink:
    def write(self, buf, n=-1):
        return n


N = int(sys.argv[1])
b = simboard.board()
fw = app.App(board=b.stim.board, rate_hz=1000, batch=10, ring_size=256, out=Sink())
fw.start()
isr = fw.sampler.isr


def loop_rate(n):
    t0 = utime.ticks_us()
    i = 0
    while i < n:
        i += 1
    return utime.ticks_diff(utime.ticks_us(), t0)


def bench():
    micropython.heap_lock()
    t0 = utime.ticks_us()
    for _ in range(N):
        isr(None)
    t_isr = utime.ticks_diff(utime.ticks_us(), t0)
    t0 = utime.ticks_us()
    fw.pump(flush=True)  # frames for everything still in the ring
    t_pump = utime.ticks_diff(utime.ticks_us(), t0)
    micropython.heap_unlock()
    return t_isr, t_pump


fw.ring.size  # noqa
# the ring holds 256 samples: time the interrupt in ring-sized rounds, framing after each
tot_isr = 0
tot_pump = 0
rounds = max(1, N // 200)
N = 200
for _ in range(rounds):
    a, c = bench()
    tot_isr += a
    tot_pump += c
n = rounds * N
print(json.dumps({"samples": n, "isr_us_per_sample": tot_isr / n, "framing_us_per_sample": tot_pump / n,
                  "loop_1e6_us": loop_rate(1000000), "overruns": fw.ring.overruns}))
