# The firmware on the scripted board through a plan of driving and parking; prints a
# PASS/FAIL line per promise and the totals (one JSON line starting "TOTALS ").
# usage: mp31_run.py BOARD VARIANT PLAN [RATE_HZ [SERVO_PERIOD_US]]
#   BOARD pico | esp32; VARIANT default (pico: PIO servo, DMA scan; esp32: PCNT servo) |
#   irq (pin-IRQ servo: no PIO, no PCNT) | cpu (pico: no DMA scan, no PIO); PLAN wrap |
#   park | trackday; RATE_HZ 500 unless given; SERVO_PERIOD_US the receiver's frame
#   period, 20000 unless given (surface receivers: 3000-11000)
import json
import sys

import utime

import fw_drive
from mptest import check, done

MIN = 60
WRAP = 1 << 30
PLANS = {
    # (seconds before the tick wrap at start, [(label, seconds, driving, receiver on)])
    "wrap": (2, [("drive", 3, True, True), ("receiver off", 1, False, False), ("drive", 2, True, True)]),
    # one park past 2^29 us (9 min): the longest stop ticks_diff can measure
    "park": (5, [("drive", 20, True, True), ("park", 10 * MIN, False, False), ("drive", 20, True, True)]),
    "trackday": (5, [("drive", 15 * MIN, True, True), ("park", 10 * MIN, False, False),
                     ("drive", 25 * MIN, True, True), ("park", 20 * MIN, False, False),
                     ("drive", 25 * MIN, True, True), ("park", 40 * MIN, False, False),
                     ("drive", 45 * MIN, True, True)]),
}

board, variant, plan = sys.argv[1], sys.argv[2], sys.argv[3]
rate = int(sys.argv[4]) if len(sys.argv) > 4 else 500
servo_period = int(sys.argv[5]) if len(sys.argv) > 5 else fw_drive.SERVO_PERIOD_US
before, steps = PLANS[plan]
opts = {"irq": {"pio": False, "pcnt": False}, "cpu": {"pio": False, "dma": False}}.get(variant, {})
t_wall = utime.ticks_ms()
d = fw_drive.Drive(board, start_ticks=WRAP - before * 1000000, rate=rate, servo_period_us=servo_period, **opts)
d.run(steps, say=lambda s: print("#", s))
tot = d.totals()
tot["wall_s"] = utime.ticks_diff(utime.ticks_ms(), t_wall) / 1000
tot["board_s"] = sum(s[1] for s in steps)
tot["rate_hz"] = rate
tot["servo_period_us"] = servo_period
tot["int_bits"] = 31 if sys.maxsize == (1 << 31) - 1 else 63
print("TOTALS " + json.dumps(tot))
n_ticks = sum(s[1] for s in steps) * 1000000 // d.period
check(tot["isr_errors"] == 0 and tot["pin_irq_errors"] == 0 and tot["main_loop_errors"] == 0,
      "no exception (MemoryError) in interrupts or the main loop: %s" % tot["last_error"])
check(tot["watchdog_resets"] == 0, "no watchdog reset")
check(tot["missed"] == 0 and tot["overruns"] == 0 and abs(tot["samples"] - n_ticks) <= 20,
      "every period a sample, all sent (%d of %d)" % (tot["samples"], n_ticks))
for what in ("index gap", "time", "time off its tick", "scan instant", "scan latched", "steer",
             "hall count", "hall edge time"):
    check(what not in tot["bad"], "%s: %d bad, first %s" % (what, tot["bad"].get(what, 0), tot["first_bad"].get(what)))
check(tot["count_steps_back"] == 0, "the wheel count never steps back")
check(tot["hall_count"] == tot["edges"] & 0xFFFF and tot["edges"] > 0,
      "every hall edge counted, no bounce (%d edges, %d bounces)" % (tot["edges"], tot["bounces"]))
check(0 < tot["stale_worst_us"] <= fw_drive.steer_stale_limit_us(servo_period),
      "steer stale within 3 servo periods (60 ms at least) of the receiver going off (%d us)" % tot["stale_worst_us"])
done()
