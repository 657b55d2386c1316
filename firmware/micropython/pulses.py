# Pulse inputs captured by pin interrupts, so the sampler never blocks on them:
# machine.time_pulse_us would stall the loop for up to a servo period and can
# return half a pulse. Each edge is timestamped in its interrupt instead.
import time
from machine import Pin
from micropython import const

from codec import add30

_MIN_PULSE_US = const(400)  # RC servo pulses are 1000-2000 us; anything far out is noise
_MAX_PULSE_US = const(2600)


def _irq(pin, handler, trigger):
    try:
        pin.irq(handler=handler, trigger=trigger, hard=True)
    except TypeError:  # ports without hard pin IRQs (their IRQs are scheduled)
        pin.irq(handler=handler, trigger=trigger)


class ServoPulse:
    """Width of the steering servo pulse (the receiver's command), in us, and the
    ticks of its falling edge: the instant the servo takes the command.

    Stale: ticks_diff is only meaningful within 2^29 us (~9 min), so no pulse may be
    judged by its age alone once the receiver has been off that long. The sampler
    reads every period: the first read that finds the latest pulse older than the
    timeout marks it stale (`_stale` = its fall), and it stays stale until a new
    pulse. A new pulse keeps the one before it (read(before=...) may need it) only
    if that one was not stale: a pulse from before an outage never comes back."""

    def __init__(self, pin_no, timeout_us):
        self._start(pin_no, timeout_us)
        self._t_rise = 0
        self._high = False
        _irq(self.pin, self._edge, Pin.IRQ_RISING | Pin.IRQ_FALLING)

    def _edge(self, pin):
        t = time.ticks_us()
        if pin.value():
            self._t_rise = t
            self._high = True
        elif self._high:
            self._high = False
            w = time.ticks_diff(t, self._t_rise)
            if _MIN_PULSE_US <= w <= _MAX_PULSE_US:
                self.new_pulse(w, t)

    def _start(self, pin_no, timeout_us):
        # the state every way of timing the pulse keeps (pin IRQs here, PIO, the ESP32's PCNT)
        self.pin = Pin(pin_no, Pin.IN)
        self.timeout_us = timeout_us
        self.width = 0
        self.t_fall = 0
        self.t_read = 0  # falling edge of the pulse the last read() returned
        self._stale = 0  # t_fall of a pulse found older than the timeout: 0 until a new edge
        self.w_prev = 0  # the pulse before the latest (read(before=...) may need it); 0: none
        self.f_prev = 0

    def new_pulse(self, w, t_fall):
        # a valid pulse of width w [us] fell at t_fall (called by whatever times it)
        self.w_prev = 0 if self.t_fall == self._stale else self.width
        self.f_prev = self.t_fall
        self.width = w
        self.t_fall = t_fall

    def read(self, now, before=-1):
        # Width of the latest valid pulse; its falling edge is left in t_read. 0 when no
        # valid pulse arrived within the timeout (receiver off, servo unplugged).
        # before >= 0: the latest pulse that ended before those ticks (the sample's
        # instant, when that is earlier than the interrupt: adc_scan).
        # Width and edge time must belong to the same pulse even where the pin IRQ can
        # run between two reads (a hard pin IRQ during the ESP32's scheduled sampler):
        # re-read if the edge time changed meanwhile (the IRQ writes width first).
        tf = self.t_fall
        w = self.width
        while self.t_fall != tf:
            tf = self.t_fall
            w = self.width
        if w == 0 or tf == self._stale:
            self.t_read = tf
            return 0
        if before >= 0 and time.ticks_diff(tf, before) >= 0:
            # the latest fell after the sample's instant (it is fresh, so the difference
            # is small and its sign true): the one before was in force
            tf = self.f_prev
            w = self.w_prev
        self.t_read = tf
        if w == 0:
            return 0
        if time.ticks_diff(now, tf) > self.timeout_us:
            if tf == self.t_fall:
                self._stale = tf
            return 0
        return w


class HallCounter:
    """Hall wheel-speed sensor: pulse count and the time of the latest pulse. An
    edge within `debounce_us` of the previous one is bounce or noise: ignored, so
    it neither adds a pulse nor moves the edge time.

    After a stop of 9 min or more ticks_diff(t, t_last) is meaningless (2^29 us), so
    the age of the latest edge is judged while it is young: snap(), which the sampler
    calls every period, marks it `_old` once it is past the debounce time. An old
    edge has no bounce and is never after a sample's instant, however long ago."""

    def __init__(self, pin_no, debounce_us=0):
        self.pin = Pin(pin_no, Pin.IN, Pin.PULL_UP)
        self.count = 0
        self.t_last = 0
        self.t_prev = 0  # the edge before t_last
        self._old = True  # t_last is known to be older than debounce_us (no edge yet: too)
        self.s_count = 0  # count and edge time as of a sample's instant (snap)
        self.s_t = 0
        self.debounce_us = debounce_us
        self.bounces = 0
        _irq(self.pin, self._edge, Pin.IRQ_FALLING)

    def _edge(self, pin):
        t = time.ticks_us()
        if not self._old and 0 <= time.ticks_diff(t, self.t_last) < self.debounce_us:
            self.bounces = add30(self.bounces, 1)
            return
        self.t_prev = self.t_last
        self.t_last = t
        self._old = False
        self.count = (self.count + 1) & 0xFFFF

    def snap(self, t, as_of_t):
        # count and latest edge time into s_count, s_t; with as_of_t, as of ticks t (the
        # sample's instant, earlier than the interrupt with adc_scan): an edge at or
        # after t is not counted yet
        # The state read whole: where the pin IRQ is hard and the sampler soft (a Pico on
        # MicroPython 1.23-1.25), an edge can land between two reads, and a count paired with
        # the next edge's time read as a one-interval speed spike. _edge writes count last: read
        # again until it is the same after the rest.
        c = self.count
        while True:
            tl = self.t_last
            tp = self.t_prev
            young = not self._old
            n = self.count
            if n == c:
                break
            c = n
        if young:
            d = time.ticks_diff(t, tl)  # the edge is young: the sign is true
            if as_of_t and d <= 0:
                c = (c - 1) & 0xFFFF
                tl = tp
            elif d >= self.debounce_us:
                self._old = True
                if self.t_last != tl:  # an edge came meanwhile: it is young (its bounce is one)
                    self._old = False
        self.s_count = c
        self.s_t = tl
