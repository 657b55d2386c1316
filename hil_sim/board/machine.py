# `machine` for the simulated board: Pin, ADC and Timer backed by simboard.
from umachine import *  # noqa: F401,F403  (whatever the unix port has)

import simboard

_b = simboard.board()


class Pin:
    IN = 0
    OUT = 1
    PULL_UP = 1
    PULL_DOWN = 2
    IRQ_RISING = 1
    IRQ_FALLING = 2

    def __init__(self, id, mode=-1, pull=-1):
        self.id = id

    def value(self, v=None):
        return _b.pin_level.get(self.id, 0)

    def irq(self, handler=None, trigger=3, hard=False):
        _b.irq[self.id] = (handler, trigger, self)


class ADC:
    ATTN_0DB = 0
    ATTN_11DB = 3

    def __init__(self, pin, atten=None):
        if not isinstance(pin, Pin):
            raise ValueError("use ADC(Pin(n)): by channel number the pad pull-down stays on (rp2)")
        if pin.id not in _b.stim.cols:
            raise ValueError("no analog signal on pin %d in this simulation" % pin.id)
        self._pin = pin.id

    def read_u16(self):
        return _b.read_u16(self._pin)

    def read_uv(self):
        return _b.read_uv(self._pin)


class Timer:
    PERIODIC = 1
    ONE_SHOT = 0

    def __init__(self, id=-1, **kw):
        if kw:
            self.init(**kw)

    def init(self, mode=1, freq=None, period=None, callback=None, hard=False):
        period_us = 1000000 // freq if freq else period * 1000
        _b.timer_period = period_us
        _b.timer_cb = callback
        _b.timer_obj = self
        _b.timer_due = _b.now + period_us

    def deinit(self):
        _b.timer_due = simboard._FAR
        _b.timer_cb = None


def idle():
    _b.idle()


def sim_finished():
    return _b.finished
