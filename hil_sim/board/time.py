# `time` for the simulated board: the virtual clock of simboard.
from utime import *  # noqa: F401,F403

import simboard

_b = simboard.board()


def ticks_us():
    return _b.ticks_us()


def ticks_ms():
    return _b.ticks_ms()


def sleep_us(us):
    _b.advance_to(_b.now + us)


def sleep_ms(ms):
    _b.advance_to(_b.now + 1000 * ms)


def sleep(s):
    _b.advance_to(_b.now + int(1000000 * s))
