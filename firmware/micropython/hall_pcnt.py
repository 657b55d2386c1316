# A hall wheel sensor counted and timed by the ESP32's pulse counter (PCNT), not by pin IRQs.
#
# On the ESP32 a pin IRQ is only scheduled (ports/esp32/machine_pin.c): an edge is timed
# when its callback runs, after any blocking UART write, and counted only then (lost when
# the 8-deep queue is full). Modelled as the port does it, 30 s at 500 Hz: edge times late
# by up to 1.6 ms on 9% of the samples, the wheel speed, (pulses between two edges) / (time
# between them), off by more than 1% on 11% (tests/test_board_esp32_hall.py).
#
# Two PCNT units per sensor, whatever the CPU does:
#   unit E counts the line's falling edges (the magnet arriving): the count is exact; its
#          glitch filter (1023 APB cycles, 12.8 us, the most the PCNT has) is the debounce;
#   unit L counts the 1 MHz clock that servo_pcnt.py's PWM puts on its clock pin, only
#          while the line is low (mode_high = HOLD): the microseconds the magnet has held
#          the line low.
# A poll (the sampler's, every period, and a scheduled callback at each edge of the line)
# reads the pin, then both units: if the line is low and this is the only edge since a
# poll that saw it high, every low microsecond counted since belongs to this pulse, so
#   edge = t - (L now - L at the last poll)                          (+-1 us)
# Otherwise (a blocking write hid the whole pulse, or two edges came between polls) the
# edge lies in a known span, [last poll, t] narrowed by the low time, and is put in its
# middle (`unanchored`). HELLO says capture.hall = "pcnt".
#
# Set up before the servo (app.py): pcnt_set_pin makes the clock pin an input (ESP-IDF
# pcnt_legacy.c, as servo_pcnt.py says), which would turn off a PWM already driving it, and
# machine_pwm.c reconnects a pin (reconfigure_pin) only for a new channel. The servo then
# starts the PWM and counts it against ticks_us; if that self-test fails there is no clock,
# and the app stops these units and takes pin interrupts instead.
import time

import esp32
from machine import Pin
from micropython import const

from pulses import _irq

_RANGE = const(32000)  # each unit's register returns to 0 at this value (h_lim)
_EDGE_FILTER = const(1023)  # APB cycles (12.5 ns): a glitch shorter than 12.8 us is no edge
_CLOCK_FILTER = const(10)


class HallCounterPcnt:
    """Same interface as pulses.HallCounter: `count` (mod 2^16), `t_last`, and snap() into
    s_count, s_t for the sampler."""

    def __init__(self, pin_no, clock_pin, units):
        self.pin = Pin(pin_no, Pin.IN, Pin.PULL_UP)
        P = esp32.PCNT
        e = P(units[0], min=-_RANGE, max=_RANGE, filter=_EDGE_FILTER)
        e.init(channel=0, pin=self.pin, rising=P.IGNORE, falling=P.INCREMENT)
        low = P(units[1], min=-_RANGE, max=_RANGE, filter=_CLOCK_FILTER)
        low.init(channel=0, pin=Pin(clock_pin), rising=P.INCREMENT, mode_pin=self.pin, mode_low=P.NORMAL,
                 mode_high=P.HOLD)
        e.start()
        low.start()
        self._e = e
        self._low = low
        self.count = 0
        self.t_last = 0
        self.t_prev = 0
        self.s_count = 0
        self.s_t = 0
        self.bounces = 0  # (the PCNT's filter drops glitches unseen)
        self.unanchored = 0  # edges no poll saw while their pulse was low: placed mid-span
        self._n = e.value()
        self._l = low.value()
        self._was_low = self.pin.value() == 0
        self._t_poll = time.ticks_us()
        # both edges: a poll when the magnet has passed (line high) lets the next edge's poll
        # give all its low time to the new pulse
        _irq(self.pin, self._edge, Pin.IRQ_RISING | Pin.IRQ_FALLING)

    def _edge(self, _pin):
        self._poll()

    def _poll(self):
        low = self.pin.value() == 0  # the pin first: if it reads low, the low time is all in
        ta = time.ticks_us()
        n = self._e.value()
        lt = self._low.value()
        t = time.ticks_add(ta, time.ticks_diff(time.ticks_us(), ta) >> 1)  # the counters' instant
        dn = n - self._n
        if dn < 0:
            dn += _RANGE
        dl = lt - self._l
        if dl < 0:
            dl += _RANGE
        since = time.ticks_diff(t, self._t_poll)
        was_low = self._was_low
        self._n = n
        self._l = lt
        self._was_low = low
        t_lo = self._t_poll  # the edges came after the last poll
        self._t_poll = t
        if dn == 0:
            return
        self.count = (self.count + dn) & 0xFFFF
        if since >= _RANGE or since < 0:  # (the low count may have wrapped: only the span is known)
            dl = since if 0 <= since < _RANGE else 0
            was_low = True
        if low and dn == 1 and not was_low:
            edge = time.ticks_add(t, -dl)  # low ever since this pulse's edge
        else:
            t_hi = t
            if low:  # low ever since the latest edge, for at most dl
                if time.ticks_diff(time.ticks_add(t, -dl), t_lo) > 0:
                    t_lo = time.ticks_add(t, -dl)
            elif dn == 1 and not was_low:  # one whole pulse between the polls: dl of the span low
                t_hi = time.ticks_add(t, -dl)
            span = time.ticks_diff(t_hi, t_lo)
            edge = time.ticks_add(t_lo, span >> 1) if span > 0 else t_hi
            self.unanchored += 1
        self.t_prev = self.t_last
        self.t_last = edge

    def snap(self, t, as_of_t):
        # count and latest edge time into s_count, s_t (the ESP32 has no ADC scan: as_of_t is
        # never asked for; the poll is the sample's own instant)
        self._poll()
        self.s_count = self.count
        self.s_t = self.t_last

    def stop(self):
        self.pin.irq(handler=None)
        self._e.deinit()
        self._low.deinit()
