# Pulse inputs captured by pin interrupts, so the sampler never blocks on them:
# machine.time_pulse_us would stall the loop for up to a servo period and can
# return half a pulse. Each edge is timestamped in its interrupt instead.
import time
from machine import Pin
from micropython import const

_MASK30 = const(0x3FFFFFFF)
_MIN_PULSE_US = const(400)  # RC servo pulses are 1000-2000 us; anything far out is noise
_MAX_PULSE_US = const(2600)


def _irq(pin, handler, trigger):
    try:
        pin.irq(handler=handler, trigger=trigger, hard=True)
    except TypeError:  # ports without hard pin IRQs (their IRQs are scheduled)
        pin.irq(handler=handler, trigger=trigger)


class ServoPulse:
    """Width of the steering servo pulse (the receiver's command), in us, and the
    ticks of its falling edge: the instant the servo takes the command."""

    def __init__(self, pin_no, timeout_us):
        self.pin = Pin(pin_no, Pin.IN)
        self.timeout_us = timeout_us
        self.width = 0
        self.t_fall = 0
        self.t_read = 0  # falling edge of the pulse the last read() returned
        self._stale = 0  # t_fall of a pulse found older than the timeout: 0 until a new edge
        self.w_prev = 0  # the pulse before the latest (read(before=...) may need it)
        self.f_prev = 0
        self._t_rise = 0
        self._high = False
        _irq(self.pin, self._edge, Pin.IRQ_RISING | Pin.IRQ_FALLING)

    def _edge(self, pin):
        t = time.ticks_us() & _MASK30
        if pin.value():
            self._t_rise = t
            self._high = True
        elif self._high:
            self._high = False
            w = time.ticks_diff(t, self._t_rise)
            if _MIN_PULSE_US <= w <= _MAX_PULSE_US:
                self.w_prev = self.width
                self.f_prev = self.t_fall
                self.width = w
                self.t_fall = t

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
        if before >= 0 and w and time.ticks_diff(tf, before) >= 0:
            tf = self.f_prev
            w = self.w_prev
        self.t_read = tf
        # ticks_diff is only meaningful within 2^29 us (~9 min): a pulse judged by its
        # age alone would come back as valid 9-17 min after the receiver was lost. The
        # sampler reads every period, so the pulse is marked stale the first time it
        # is over the timeout and stays stale until a new falling edge.
        if tf == self._stale or w == 0:
            return 0
        if time.ticks_diff(now, tf) > self.timeout_us:
            self._stale = tf
            return 0
        return w


class HallCounter:
    """Hall wheel-speed sensor: pulse count and the time of the latest pulse. An
    edge within `debounce_us` of the previous one is bounce or noise: ignored, so
    it neither adds a pulse nor moves the edge time."""

    def __init__(self, pin_no, debounce_us=0):
        self.pin = Pin(pin_no, Pin.IN, Pin.PULL_UP)
        self.count = 0
        self.t_last = 0
        self.t_prev = 0  # the edge before t_last
        self.s_count = 0  # count and edge time as of a sample's instant (snap)
        self.s_t = 0
        self.debounce_us = debounce_us
        self.bounces = 0
        _irq(self.pin, self._edge, Pin.IRQ_FALLING)

    def _edge(self, pin):
        t = time.ticks_us() & _MASK30
        if self.count and time.ticks_diff(t, self.t_last) < self.debounce_us:
            self.bounces += 1
            return
        self.t_prev = self.t_last
        self.t_last = t
        self.count = (self.count + 1) & 0xFFFF

    def snap(self, t, as_of_t):
        # count and latest edge time into s_count, s_t; with as_of_t, as of ticks t (the
        # sample's instant, earlier than the interrupt with adc_scan): an edge at or
        # after t is not counted yet
        c = self.count
        tl = self.t_last
        if as_of_t and c and time.ticks_diff(tl, t) >= 0:
            c = (c - 1) & 0xFFFF
            tl = self.t_prev
        self.s_count = c
        self.s_t = tl
