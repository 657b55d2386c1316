# Steering servo pulses timed by the ESP32's pulse counter (PCNT), not by pin IRQs.
#
# On the ESP32 a pin IRQ is only scheduled (ports/esp32/machine_pin.c: the ISR calls
# mp_sched_schedule; Pin.irq has no `hard`): an edge is timed when its callback runs,
# after any blocking UART write, and the 8-deep queue it shares with the (soft)
# sampler can be full. Modelled as the port does it, 5% of the pulses were missed and
# 7% of those seen were off by more than 100 us (tests/test_board_esp32_servo.py).
#
# The PCNT counts in hardware whatever the CPU does. machine.PWM puts a 1 MHz clock on
# a spare pin (LEDC from the 80 MHz APB clock: the crystal that also drives ticks_us),
# and PCNT unit A counts its rising edges only while the servo line is high (the
# servo pin is the unit's control input, mode_low = HOLD): the count grows by exactly
# the pulse's width in us, +-1. Unit B counts the servo's rising edges. The sampler
# (and a scheduled callback at each edge) polls both:
#   width = the counts gained since the last poll that saw the line low;
#   fall  = t + (count now - count at t), where t is a poll that saw the line high
#           (an anchor). A pulse no poll saw high (a write blocked the loop for all of
#           it) lies in a known span: a receiver sends its pulses at a steady period,
#           learnt from the anchored pulses' rising edges, so its rise is put on that
#           period's grid when the grid crosses the span, else mid-span.
# Unit B tells a poll gap that held two pulses (their counts add up): dropped.
#
# The clock pin only carries the clock: leave it unconnected. The PCNT must be set up
# before the PWM on that pin: ESP-IDF's pcnt_set_pin makes the pin an input
# (gpio_set_direction(GPIO_MODE_INPUT)); the PWM then drives the pad and keeps its
# input on (machine_pwm.c, reconfigure_pin), so the unit reads its own pin. A self-test
# at start counts the clock for 2 ms against ticks_us; if the count is wrong (a
# MicroPython where that does not hold) the firmware falls back to pin IRQs and HELLO
# says so.
import time

import esp32
from machine import PWM, Pin
from micropython import const

from pulses import ServoPulse, _irq

_RANGE = const(32000)  # the counter returns to 0 at this value (PCNT h_lim), as machine.Counter sets it
_CLOCK_HZ = const(1000000)  # one count per us
_TEST_US = const(2000)
_MIN_PULSE_US = const(400)
_MAX_PULSE_US = const(2600)
_FILTER = const(10)  # APB cycles (12.5 ns): glitches under 125 ns on the inputs are ignored
_PERIOD_MIN_US = const(2500)  # receiver frame periods believed (333 Hz .. 20 Hz)
_PERIOD_MAX_US = const(50000)
_PERIOD_TOL_X16 = const(800)  # a rise within 50 us of the grid confirms the period
_PERIOD_CONFIRMED = const(3)
_PREDICT_MAX_US = const(400000)  # not from a rise older than this (and no int >= 2^30)


class ServoPulsePcnt(ServoPulse):
    """Same interface as pulses.ServoPulse: width [us] and falling-edge ticks of the
    latest valid pulse; read(now) is called by the sampler every period."""

    def __init__(self, pin_no, timeout_us, clock_pin, units=(0, 1)):
        self._start(pin_no, timeout_us)
        self.unanchored = 0  # pulses no poll saw high: fall time from the span it lies in
        self.merged = 0  # poll gaps that held more than one pulse: dropped
        clk = Pin(clock_pin)
        P = esp32.PCNT
        a = P(units[0], min=-_RANGE, max=_RANGE, filter=_FILTER)
        # first count the clock whatever the servo line does: the self-test
        a.init(channel=0, pin=clk, rising=P.INCREMENT, mode_pin=self.pin, mode_low=P.NORMAL,
               mode_high=P.NORMAL)
        self._pwm = PWM(clk, freq=_CLOCK_HZ, duty_u16=32768)  # after the PCNT: see above
        a.start()
        t0 = time.ticks_us()
        v0 = a.value()
        time.sleep_us(_TEST_US)
        v1 = a.value()
        dt = time.ticks_diff(time.ticks_us(), t0)
        n = (v1 - v0) % _RANGE
        if not dt - (dt >> 3) <= n <= dt + 8:
            self.stop()
            a.deinit()
            raise OSError("PCNT counted %d clock edges in %d us" % (n, dt))
        a.init(rising=P.INCREMENT, mode_low=P.HOLD, mode_high=P.NORMAL, value=0)
        b = P(units[1], min=-_RANGE, max=_RANGE, filter=_FILTER)
        b.init(channel=0, pin=self.pin, rising=P.INCREMENT, mode_low=P.NORMAL, mode_high=P.NORMAL)
        b.start()
        self._a = a
        self._b = b
        self._v = a.value()
        self._r = b.value()
        # a pulse under way now is counted short: poisoned, so it is not taken
        self._acc = _MAX_PULSE_US + 1 if self.pin.value() else 0  # us counted of the pulse under way
        self._rises = 0  # rising edges since the last pulse was taken
        self._anchor_t = -1  # ticks of a poll that saw the line high in this pulse (-1: none)
        self._anchor_acc = 0
        self._t_last = time.ticks_us()
        self._rise_t = -1  # ticks of the latest anchored pulse's rising edge (-1: none)
        self._p16 = 0  # the receiver's period [us / 16], 0: not known
        self._confirmed = 0  # rises that fell on the period's grid in a row
        # A poll while the line is high anchors the falling edge; one while it is low closes
        # the pulse. A scheduled callback at each edge gives most pulses both, whatever the
        # sampler's phase: a receiver at 333 Hz (3 ms frames, ~1 ms low between pulses)
        # leaves the sampler's polls (every 10 ms at 100 Hz) no low poll between two pulses,
        # and counts that span two pulses cannot be split (dropped, `merged`).
        _irq(self.pin, self._edge, Pin.IRQ_RISING | Pin.IRQ_FALLING)

    def _edge(self, _pin):
        self._poll()

    def _poll(self):
        # The pin first: if it reads low, the pulse's counts are all in (one that ends
        # between this read and the counter's adds nothing after it).
        high = self.pin.value()
        ta = time.ticks_us()
        v = self._a.value()
        r = self._b.value()
        t = time.ticks_add(ta, time.ticks_diff(time.ticks_us(), ta) >> 1)  # the counters' instant
        d = v - self._v
        if d < 0:
            d += _RANGE
        self._v = v
        dr = r - self._r
        if dr < 0:
            dr += _RANGE
        self._r = r
        self._rises += dr
        acc = self._acc + d
        if acc > _MAX_PULSE_US:
            acc = _MAX_PULSE_US + 1  # a line held high: no valid pulse, and no growth
        t_last = self._t_last
        self._t_last = t
        if high:
            self._acc = acc
            self._anchor_t = t
            self._anchor_acc = acc
            return
        if acc == 0:
            return
        # a pulse ended since the last poll
        if self._anchor_t >= 0:
            fall = time.ticks_add(self._anchor_t, acc - self._anchor_acc)
            self._learn_period(time.ticks_add(fall, -acc))
        else:  # the whole pulse between two polls: it fell between acc after t_last and t
            fall = self._place(acc, time.ticks_add(t_last, acc), t)
            self.unanchored += 1
        rises = self._rises
        self._acc = 0
        self._rises = 0
        self._anchor_t = -1
        if rises > 1:
            self.merged += 1
            return
        if _MIN_PULSE_US <= acc <= _MAX_PULSE_US:
            self.w_prev = self.width
            self.f_prev = self.t_fall
            self.width = acc
            self.t_fall = fall

    def _learn_period(self, rise):
        # the receiver's frame period from consecutive exact rises (n periods apart)
        if self._rise_t >= 0:
            gap = time.ticks_diff(rise, self._rise_t)
            p16 = self._p16
            if p16 and 0 < gap < _PREDICT_MAX_US:
                n = (gap * 16 + (p16 >> 1)) // p16
                err = gap * 16 - n * p16
                if 1 <= n <= 8 and -_PERIOD_TOL_X16 <= err <= _PERIOD_TOL_X16:
                    self._p16 = p16 + err // (4 * n)  # follows the receiver's clock slowly
                    if self._confirmed < _PERIOD_CONFIRMED:
                        self._confirmed += 1
                else:
                    p16 = 0
            if not p16:
                self._confirmed = 0
                self._p16 = gap * 16 if _PERIOD_MIN_US <= gap <= _PERIOD_MAX_US else 0
        self._rise_t = rise

    def _place(self, width, lo, hi):
        # the fall of a pulse no poll saw high lies in [lo, hi]: on the receiver's period
        # grid when that is known and crosses the span, else in its middle
        span = time.ticks_diff(hi, lo)
        if span < 0:
            return hi
        mid = time.ticks_add(lo, span >> 1)
        if self._confirmed < _PERIOD_CONFIRMED:
            return mid
        since = time.ticks_diff(mid, self._rise_t) - width  # from the last known rise to this one
        if not 0 < since < _PREDICT_MAX_US:
            return mid
        p16 = self._p16
        n = (since * 16 + (p16 >> 1)) // p16
        fall = time.ticks_add(self._rise_t, (n * p16 + 8) // 16 + width)
        if time.ticks_diff(fall, lo) < 0 or time.ticks_diff(hi, fall) < 0:
            return mid
        return fall

    def read(self, now, before=-1):
        # the counts become width and edge here; which pulse counts and when it is stale
        # is pulses.ServoPulse's rule, shared
        self._poll()
        return ServoPulse.read(self, now, before)

    def stop(self):
        self.pin.irq(handler=None)
        self._pwm.deinit()
