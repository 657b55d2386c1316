# A board for the firmware, driven by a script of events, that holds to the boards'
# integer rules: every value the firmware can reach while an interrupt runs (ticks,
# pin levels, ADC counts, the PIO FIFO, the DMA ring) is a small int below 2^30,
# prepared before the interrupt. The firmware runs unchanged (machine.py, rp2.py and
# time.py beside this file are what it imports). It runs on the webassembly port,
# whose small ints are 31-bit as on the RP2040 and the ESP32, and on the unix port.
#
# What it models, from the MicroPython sources (ports/rp2, ports/esp32, extmod):
# - ticks_us / ticks_ms wrap at 2^30 (time.py); ticks_add refuses |delta| >= 2^29.
# - Hard interrupts (rp2: Timer(hard=True), Pin.irq(hard=True)) run with the heap
#   locked; an exception in a hard timer callback stops that timer for good
#   (ports/rp2/machine_timer.c, alarm_callback). ESP32: Timer(hard=True) is a
#   ValueError, Pin.irq has no `hard` (TypeError): both are scheduled.
# - machine.WDT resets the board when not fed within its timeout; the script asks
#   `wdt_expired()` and counts it.
# - The RP2040 PIO program of servo_pio.py: its RX FIFO (8 words, joined) receives
#   X (rise + 2 us) and Y (fall + 4 us) of each pulse, 30 bits of a 32-bit
#   down-counter started with the state machine (tests/test_board_capture.py runs the
#   assembled program cycle by cycle; here only its output words).
# - The RP2040 ADC round robin into the DMA ring (adc_scan.py): scan k of all four
#   inputs ends at t0 + (k + 1) * scan_us; the ring slot the sampler is about to
#   latch is filled, before the interrupt, with the scan number that is in it then.
# - The ESP32 pulse counter (esp32.PCNT, ports/esp32/esp32_pcnt.c over ESP-IDF's
#   legacy driver) and a PWM clock (machine.PWM, LEDC): a unit counts the edges of its
#   pulse pin (INCREMENT / IGNORE), gated by its control pin (mode_low / mode_high:
#   NORMAL counts, HOLD does not), in a 16-bit register that returns to 0 at `max`.
#   A 1 MHz PWM has its rising edges half way between two microseconds, so a unit
#   counting it gains exactly the microseconds its control line was high. As on the
#   chip, a PCNT set up on a pin the PWM already drives turns its output off
#   (pcnt_set_pin makes it an input); a PWM started after it keeps the input on.
#   The counts move when the clock does (advance_to) and at pin edges, outside any
#   interrupt: reading a unit inside one only returns a small int.
# What it does not: the interrupt's own duration, a pin IRQ waiting for a running
# one, the scheduler queue (hil_sim/board/simboard.py models those).
from array import array

import utime

MASK30 = 0x3FFFFFFF
_HALF = 0x20000000
_PORT_WRAPS_AT_2_30 = utime.ticks_add(MASK30, 1) == 0  # 32-bit ports; the unix port's is 2^62


class Board:
    def __init__(self, name, start_ticks=0, pio=True, dma=True, pcnt=True):
        self.name = name  # "pico" or "esp32"
        self.pio = pio and name == "pico"
        self.dma = dma and name == "pico"
        self.pcnt = pcnt and name == "esp32"
        self.units = [PcntUnit(self) for _ in range(8)]  # ESP32: 8 PCNT units
        self.clock_pins = {}  # pin -> True while a 1 MHz PWM drives it (False: its output off)
        self.abs_us = 0  # board time since power-on [us]: the script's clock (a big int on 31 bits)
        self.start_ticks = start_ticks  # the us counter at power-on (near 2^30: the wrap comes soon)
        self.ticks = start_ticks & MASK30  # what ticks_us() returns
        self.ticks_ms = (start_ticks // 1000) & MASK30
        self.level = {}  # pin -> level
        self.irq = {}  # pin -> [handler, trigger, Pin, hard]
        self.adc_u16 = {}  # pin -> read_u16 value
        self.adc_uv = {}  # pin -> read_uv value
        self.timer_cb = None
        self.timer_hard = False
        self.timer_period = 0
        self.timer_due = -1  # abs_us of the next tick; -1: stopped
        self.wdt_timeout_ms = 0
        self.wdt_fed_ms = 0  # ticks_ms of the last feed
        self.wdt_scratch4 = 0
        self.reset_cause = 1  # PWRON_RESET
        self.sm = None
        self.dmas = []
        self.scan_t0_abs = -1  # abs_us at which the ADC round robin started
        self.scan_us = 0
        self.isr_errors = 0
        self.last_error = None
        self.hard_edge_errors = 0

    # -- clock --------------------------------------------------------------
    def advance_to(self, abs_us):
        # moves the clock forward, outside any interrupt (big ints are fine here). As on
        # rp2, both ticks come from one 64-bit us counter, each kept to 30 bits.
        if abs_us < self.abs_us:
            raise ValueError("the clock only moves forward")
        if self.pcnt:
            for u in self.units:
                u.clock(abs_us - self.abs_us)
        self.abs_us = abs_us
        t64 = self.start_ticks + abs_us
        self.ticks = t64 & MASK30
        self.ticks_ms = (t64 // 1000) & MASK30

    # -- interrupts -----------------------------------------------------------
    def fire_pin(self, pin, level):
        # the pin changes level; its IRQ runs if it triggers (hard: heap locked)
        if self.pcnt:
            for u in self.units:
                u.edge(pin, level)
        self.level[pin] = level
        h = self.irq.get(pin)
        if h is None:
            return
        handler, trig, obj, hard = h
        if (level and trig & 1) or (not level and trig & 2):
            e = call_locked(handler, obj)
            if e is not None:
                self.hard_edge_errors += 1
                self.last_error = e

    def glitch(self, pin, level, us):
        # the pin goes to `level` for `us` microseconds (glitch_end brings it back): pin IRQs
        # see both edges; a pulse counter whose filter is longer than the glitch counts neither
        # (a unit gated by the pin does follow it: its own filter is short enough for a 1 MHz
        # clock)
        for u in self.units:
            u.filtering = u.pin == pin and u.filter_us > us
        self.fire_pin(pin, level)

    def glitch_end(self, pin, level):
        self.fire_pin(pin, level)
        for u in self.units:
            u.filtering = False

    def fire_timer(self):
        # one timer tick, heap locked (hard on rp2; scheduled on the ESP32, but the
        # firmware promises no allocation there either); rp2 drops a hard timer that raised
        e = call_locked(self.timer_cb, None)
        if self.timer_due >= 0:
            self.timer_due += self.timer_period
        if e is not None:
            self.isr_errors += 1
            self.last_error = e
            if self.timer_hard:
                self.timer_due = -1

    def wdt_expired(self):
        return self.wdt_timeout_ms and ticks_diff(self.ticks_ms, self.wdt_fed_ms) > self.wdt_timeout_ms

    # -- PIO and DMA ----------------------------------------------------------
    def pio_pulse(self, abs_rise, abs_fall):
        # the state machine timed a pulse: push X then Y (30 bits of its counter)
        sm = self.sm
        if sm is None or not sm.running:
            return
        er = abs_rise - sm.abs_start + 2
        ef = abs_fall - sm.abs_start + 4
        sm.push((~er) & MASK30)
        sm.push((~ef) & MASK30)

    def dma_fill(self, scan):
        # the ring slot the sampler latches next holds, now, the newest scan of that slot:
        # its number (mod 4096) in every input, so a record tells which scan it came from
        if self.scan_t0_abs < 0:
            return
        done = (self.abs_us - self.scan_t0_abs) // self.scan_us - 1  # newest complete scan
        slot = scan._slot
        k = done - ((done - slot) % scan.scans)
        v = k & 0xFFF
        off = slot << 3
        buf = scan.buf
        i = 0
        while i < 8:
            buf[off + i] = v & 0xFF
            buf[off + i + 1] = v >> 8
            i += 2
        for d in self.dmas:
            if d.base:  # the channel that writes the ring: at the scan being filled
                d.write = d.base + (((done + 1) % scan.scans) << 3)


class PcntUnit:
    """One ESP32 pulse counter unit, channel 0 (what the firmware uses)."""

    IGNORE = 0  # PCNT_COUNT_DIS / INC / DEC, PCNT_MODE_KEEP / REVERSE / DISABLE
    INCREMENT = 1
    NORMAL = 0
    HOLD = 2

    def __init__(self, board):
        self.board = board
        self.deinit()

    def deinit(self):
        self.pin = -1
        self.ctrl = -1
        self.rising = self.falling = PcntUnit.IGNORE
        self.mode_low = self.mode_high = PcntUnit.NORMAL
        self.h_lim = 0
        self.reg = 0
        self.running = False
        self.filter_us = 0  # the glitch filter (PCNT `filter`, APB cycles of 12.5 ns), in us
        self.filtering = False  # inside a glitch the filter removes

    def set_pins(self, pin, ctrl):
        self.pin = pin
        self.ctrl = ctrl
        if pin in self.board.clock_pins:  # pcnt_set_pin: GPIO_MODE_INPUT, the PWM's output off
            self.board.clock_pins[pin] = False

    def _counts(self):
        # the control line lets it count now (an unused control input: both modes the same here)
        if self.ctrl < 0:
            return self.mode_low == PcntUnit.NORMAL
        high = self.board.level.get(self.ctrl, 0)
        return (self.mode_high if high else self.mode_low) == PcntUnit.NORMAL

    def _add(self, n):
        r = self.reg + n
        if self.h_lim > 0:
            r %= self.h_lim  # back to 0 each time it reaches max
        self.reg = r

    def clock(self, dt_us):
        # the clock on the pulse pin over dt_us: one rising edge per us (1 MHz, edges at +0.5 us)
        if self.running and dt_us > 0 and self.board.clock_pins.get(self.pin) and self._counts():
            if self.rising == PcntUnit.INCREMENT:
                self._add(dt_us)
            if self.falling == PcntUnit.INCREMENT:
                self._add(dt_us)

    def edge(self, pin, level):
        # a pin edge, before the board's level changes
        if self.running and pin == self.pin and not self.filtering and self._counts():
            if (self.rising if level else self.falling) == PcntUnit.INCREMENT:
                self._add(1)


def ticks_diff(a, b):
    if _PORT_WRAPS_AT_2_30:
        return utime.ticks_diff(a, b)
    return ((a - b + _HALF) & MASK30) - _HALF


def call_locked(handler, arg):
    # run an interrupt handler with the heap locked; its exception, or None
    import micropython

    micropython.heap_lock()
    try:
        handler(arg)
        e = None
    except Exception as x:  # noqa: BLE001 - whatever the board would catch
        e = x
    micropython.heap_unlock()
    return e


class StateMachine:
    def __init__(self, board):
        self.board = board
        self.fifo = array("i", [0] * 8)
        self.n = 0
        self.head = 0
        self.running = False
        self.abs_start = 0
        self.dropped = 0

    def active(self, v=None):
        if v is None:
            return self.running
        if v and not self.running:
            self.abs_start = self.board.abs_us
        self.running = bool(v)

    def push(self, w):
        if self.n == 8:  # push noblock: a full FIFO drops the word
            self.dropped += 1
            return
        self.fifo[(self.head + self.n) & 7] = w
        self.n += 1

    def rx_fifo(self):
        return self.n

    def get(self):
        w = self.fifo[self.head]
        self.head = (self.head + 1) & 7
        self.n -= 1
        return w


BOARD = None


def board():
    return BOARD


def new_board(name, **kw):
    global BOARD
    BOARD = Board(name, **kw)
    return BOARD
