# Steering servo pulses timed by an RP2040 PIO state machine, not by a pin IRQ.
#
# A pin IRQ timestamps an edge when its handler runs: on the RP2040 pin and timer
# IRQs share one priority, so an edge during the sampler interrupt is timed when
# that ends (~100 us late on ~5% of pulses with a 100 us sampler). The state
# machine below keeps its own microsecond counter and samples the pin every 1 us
# whatever the CPU does; the sampler interrupt drains its FIFO.
#
# The program: at 2 MHz every instruction is 0.5 us, and every path is built of
# pairs (one `jmp y--` and one other instruction), so Y falls by exactly one per
# microsecond, edges and pushes included: it is a free-running us counter that
# never drifts from ticks_us (same crystal). At each rising edge X = Y; at each
# falling edge it pushes X and then Y, 30 bits each (so sm.get() returns small
# ints). Counted from Y's start, X holds the rise + 2 us and Y the fall + 4 us (the
# 2-cycle input synchroniser, the edge found within one 2-cycle loop, the
# decrements on the way to the push), each +-0.5 us: so
#   width = X - Y - 2 us, fall = start + ~Y - 4 us  (+-1 us).
# tests/test_board_capture.py finds these offsets by running the assembled program
# cycle by cycle.
# 17 of the PIO block's 32 instructions. The RX FIFO is joined (8 words: 4 pulses,
# 80 ms of servo frames); the sampler drains it every period.
import time

import rp2
from machine import Pin
from micropython import const

from codec import add30
from pulses import ServoPulse

_MASK30 = const(0x3FFFFFFF)
_HALF30 = const(0x20000000)
_MIN_PULSE_US = const(400)
_MAX_PULSE_US = const(2600)
_WIDTH_EXTRA_US = const(2)
_FALL_LAG_US = const(4)
SM_FREQ = 2000000


@rp2.asm_pio(in_shiftdir=rp2.PIO.SHIFT_LEFT, fifo_join=rp2.PIO.JOIN_RX)
def pulse_counter():
    mov(y, invert(null))  # noqa: F821  (asm_pio names)
    label("low")  # noqa: F821
    jmp(pin, "rise")  # noqa: F821
    jmp(y_dec, "low")  # noqa: F821
    label("rise")  # noqa: F821
    jmp(y_dec, "r1")  # noqa: F821
    label("r1")  # noqa: F821
    mov(x, y)  # noqa: F821
    jmp(y_dec, "high")  # noqa: F821
    label("high")  # noqa: F821
    jmp(pin, "h1")  # noqa: F821
    jmp(y_dec, "f1")  # noqa: F821
    label("f1")  # noqa: F821
    in_(x, 30)  # noqa: F821
    jmp(y_dec, "f2")  # noqa: F821
    label("f2")  # noqa: F821
    push(noblock)  # noqa: F821
    jmp(y_dec, "f3")  # noqa: F821
    label("f3")  # noqa: F821
    in_(y, 30)  # noqa: F821
    jmp(y_dec, "f4")  # noqa: F821
    label("f4")  # noqa: F821
    push(noblock)  # noqa: F821
    jmp(y_dec, "low")  # noqa: F821
    label("h1")  # noqa: F821
    jmp(y_dec, "high")  # noqa: F821


class ServoPulsePio(ServoPulse):
    """Same interface as pulses.ServoPulse: width [us] and falling-edge ticks of the
    latest valid pulse; read(now) is called by the sampler every period."""

    def __init__(self, pin_no, timeout_us, sm_id=0):
        self._start(pin_no, timeout_us)
        self.resyncs = 0  # word pairs that did not make a pulse: one word dropped to realign
        self._sm = rp2.StateMachine(sm_id, pulse_counter, freq=SM_FREQ, jmp_pin=self.pin)
        t_a = time.ticks_us()
        # a pulse already under way when the machine starts is measured short: drop it
        self._first = self.pin.value() == 1
        self._sm.active(1)
        t_b = time.ticks_us()
        self.t0 = time.ticks_add(t_a, time.ticks_diff(t_b, t_a) >> 1)  # ticks when Y started

    def _drain(self):
        sm = self._sm
        while sm.rx_fifo() >= 2:
            rise = sm.get()
            fall = sm.get()
            w = ((rise - fall) & _MASK30) - _WIDTH_EXTRA_US
            if not _MIN_PULSE_US <= w <= _MAX_PULSE_US:
                # a glitch, or a pair split by a full FIFO: drop one word, realign
                if w < 0 or w > 30000:
                    self.resyncs = add30(self.resyncs, 1)
                    if sm.rx_fifo():
                        sm.get()
                continue
            if self._first:
                self._first = False
                continue
            # us since Y started, mod 2^30, made signed: ticks_add takes |delta| < 2^29 only
            d = ((~fall) & _MASK30) - _FALL_LAG_US
            if d >= _HALF30:
                d = d - _MASK30 - 1
            self.new_pulse(w, time.ticks_add(self.t0, d))

    def read(self, now, before=-1):
        # the state machine's words become width and edge here; which pulse counts and
        # when it is stale is pulses.ServoPulse's rule, shared (the tear re-read is a no-op
        # here: nothing writes the fields between two reads)
        self._drain()
        return ServoPulse.read(self, now, before)

    def stop(self):
        self._sm.active(0)
