# `time` for the simulated board: the virtual clock of simboard, with ticks that
# wrap at 2^30 as on every MicroPython board (the unix port's own wrap at 2^62,
# so its ticks_diff would hide every wrap bug).
from utime import *  # noqa: F401,F403

import simboard

_b = simboard.board()
_MASK30 = 0x3FFFFFFF
_HALF = 0x20000000


def ticks_us():
    return _b.ticks_us()


def ticks_ms():
    return _b.ticks_ms()


def ticks_diff(a, b):
    # signed difference in (-2^29, 2^29], as MicroPython's ticks_diff on a board
    return ((a - b + _HALF) & _MASK30) - _HALF


def ticks_add(t, delta):
    # the ports refuse a delta that ticks_diff could not give back (extmod/modtime.c)
    if not -_HALF < delta < _HALF:
        raise OverflowError("ticks interval overflow")
    return (t + delta) & _MASK30


def sleep_us(us):
    _b.advance_to(_b.now + us)
    _b.run_scheduled()


def sleep_ms(ms):
    sleep_us(1000 * ms)


def sleep(s):
    sleep_us(int(1000000 * s))
