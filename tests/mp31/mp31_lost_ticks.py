# Nine minutes of lost timer ticks, then a call: the sampler steps its grid over the lost
# periods with time.ticks_add, which takes |delta| < 2^29 only (extmod/modtime.c raises
# OverflowError). The lost span is measured by ticks_diff (< 2^29), but k whole periods
# (k * period = lost span + up to one period) can pass 2^29: the firmware before 0.3.3 raised
# there, in the timer callback. On a soft timer (the ESP32) the main loop can run bytecode
# while every tick finds the scheduler queue full; the scripted board stages that directly:
# the main loop's `t_free` ~9 min after the last served tick, then the next tick's call.
# usage: mp31_lost_ticks.py BOARD (pico: hard timer with the ADC scan; esp32: soft timer)
import sys

import fw_drive
import scripted_board
from mptest import check, done

WRAP = 1 << 30
board = sys.argv[1]
b = scripted_board.new_board(board, start_ticks=WRAP - 3000000)
import app  # noqa: E402  (after the board: the firmware imports machine)
import time  # noqa: E402

sink = fw_drive.Sink(4000)
fw = app.App(board=board, rate_hz=500, batch=10, out=sink, watchdog=False)
sink.app = fw
fw.start()
s = fw.sampler
P = s.period_us


def tick(late_us=0):
    if b.timer_due < 0:  # a hard timer that raised is stopped for good (rp2)
        return
    b.advance_to(b.timer_due + late_us)
    if fw.scan is not None:
        b.dma_fill(fw.scan)
    b.fire_timer()
    e = fw_drive._main_loop(fw)
    if e is not None:
        b.loop_error = e


for _ in range(50):
    tick()
idx0 = s.index  # the index of the next tick, at abs time b.timer_due
abs_next = b.timer_due
# the lost span: t_free - t_next - margin = m whole periods, the largest m whose span
# ticks_diff still measures; k = m + 1 periods are then lost, and k * P passes 2^29
m = ((1 << 29) - 1 - 200) // P
check((m + 1) * P >= 1 << 29, "the staged loss needs a step of 2^29 or more (%d periods of %d us)" % (m + 1, P))
b.advance_to(abs_next + m * P + 200)
s.t_free = time.ticks_us()  # the main loop ran bytecode here; no tick was served since abs_next
b.timer_due = abs_next + (m + 1) * P  # the first tick after t_free
n_before = sink.n
tick(late_us=30)
check(b.isr_errors == 0, "no exception in the timer callback (%r)" % (b.last_error,))
check(s.missed == m + 1, "the lost periods counted: %d (expected %d)" % (s.missed, m + 1))
for _ in range(60):
    tick()
fw.pump(flush=True)
check(b.isr_errors == 0 and getattr(b, "loop_error", None) is None,
      "no exception afterwards (%r)" % (getattr(b, "loop_error", None),))
# the samples after the loss: their indices skip exactly the lost periods, and each sample is
# at its own tick (or, with the RP2040's scan, one to four scans before it)
ok_idx = ok_t = True
j = n_before
k = 0
while j < sink.n:
    idx = sink.idx[j]
    want_idx = (idx0 + m + 1 + k) & 0x3FFFFFFF
    tick_ticks = (b.start_ticks + abs_next + (m + 1 + k) * P) & 0x3FFFFFFF
    back = ((tick_ticks - sink.t[j] + 0x20000000) & 0x3FFFFFFF) - 0x20000000
    if idx != want_idx:
        ok_idx = False
    if fw.scan is None:
        if back != (-30 if k == 0 else 0):
            ok_t = False
    elif not b.scan_us <= back <= 4 * b.scan_us + (30 if k == 0 else 0):
        ok_t = False
    j += 1
    k += 1
check(k == 61, "the 61 samples after the loss were sent (%d)" % k)
check(ok_idx, "their indices skip exactly the lost periods")
check(ok_t, "each sample at its own tick")
done()
