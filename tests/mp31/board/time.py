# `time` for the scripted board: its clock, and ticks_add / ticks_diff as on a board
# (the port's own where they wrap at 2^30, i.e. on a 32-bit port such as webassembly;
# else the same arithmetic in Python, refusing what the ports refuse).
from utime import *  # noqa: F401,F403

import scripted_board
import utime as _ut

_HALF = 0x20000000
_MASK30 = 0x3FFFFFFF


def ticks_us():
    return scripted_board.BOARD.ticks


def ticks_ms():
    return scripted_board.BOARD.ticks_ms


def sleep_us(us):
    # the board's clock moves on (outside any interrupt: servo_pcnt's self-test at start)
    b = scripted_board.BOARD
    b.advance_to(b.abs_us + us)


def sleep_ms(ms):
    sleep_us(ms * 1000)


if _ut.ticks_add(_MASK30, 1) == 0:
    ticks_add = _ut.ticks_add
    ticks_diff = _ut.ticks_diff
else:
    def ticks_diff(a, b):
        return ((a - b + _HALF) & _MASK30) - _HALF

    def ticks_add(t, delta):
        if not -_HALF < delta < _HALF:  # extmod/modtime.c
            raise OverflowError("ticks interval overflow")
        return (t + delta) & _MASK30
