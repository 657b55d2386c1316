# The RP2040 peripherals the firmware drives directly, for the simulated board:
# the ADC (its registers through machine.mem32), the DMA channels (rp2.DMA) and a
# PIO state machine (rp2.StateMachine), on simboard's virtual clock.
#
# What the model does (RP2040 datasheet 4.9 ADC, 2.5 DMA; MicroPython's
# ports/rp2/rp2_dma.c and rp2_pio.c for the API):
# - ADC: CS.EN, CS.AINSEL, CS.RROBIN, CS.START_MANY; DIV (INT.FRAC cycles of 48 MHz,
#   at least 96: back to back); FCS.EN, FCS.DREQ_EN, LEVEL (reads), OVER. While
#   START_MANY is set it converts input after input of the round-robin mask at exact
#   instants start + k * period, each value the stimulus voltage at that instant
#   (12 bits over 0..3.3 V; AIN4, the temperature sensor, ~0.706 V). Results enter
#   the 4-deep FIFO; with DREQ_EN a DMA channel paced by DREQ 36 takes each at once,
#   without one they overflow (OVER) and are lost.
# - machine.ADC.read_u16 while START_MANY runs raises: on the chip it would select
#   another input and break the round robin's order.
# - DMA: config/pack_ctrl/active/count/write/registers/channel as rp2.DMA. The
#   channel reading the ADC FIFO must be paced by DREQ_ADC (36) and must not
#   increment its read address; its write ring (ring_sel, ring_size) must be aligned
#   to its size (else the hardware wraps elsewhere): both are checked and refused
#   with the reason. When its count runs out it triggers its chain_to channel; a
#   channel that writes one word to the first one's AL1_TRANS_COUNT_TRIG register
#   re-arms it (the firmware's reload), anything else is refused.
# - PIO: rp2.asm_pio records the program (instruction names and operands, <= 32);
#   the state machine is emulated at the level of its RX FIFO: on each falling edge
#   of its jmp pin it pushes the two words the firmware's program pushes (rise and
#   fall counter, from the cycle count that tests/test_board_capture.py checks on
#   the assembled program with a cycle-level interpreter), 8 words deep (JOIN_RX),
#   a push into a full FIFO lost. The edges it sees are the stimulus's exact times:
#   interrupts do not delay it.
# What it does not model: conversion noise and the ADC's INL/DNL, FCS.THRESH/ERR/
# SHIFT, the ADC IRQ, DMA bus timing and priorities, other DREQs, any PIO program
# other than the firmware's (the emulation reads no instructions at run time).
#
# Nothing here allocates once running (the firmware's heap test runs through it).
import struct
from array import array

import micropython

ADC_BASE = 0x4004C000
CS, FCS, FIFO, DIV = ADC_BASE, ADC_BASE + 8, ADC_BASE + 12, ADC_BASE + 16
DREQ_ADC = 36
_PERMANENT = 0x3F
_MASK32 = 0xFFFFFFFF


class HwError(Exception):
    """The firmware drove the peripheral in a way the chip would not do what it means."""


@micropython.viper
def _fill(buf: ptr8, volts: ptr16, p: ptr32, cols: ptr8) -> int:
    # Write p[2] conversions into the DMA ring: byte offset p[0] (mask p[1]); the first
    # is order entry p[8] of p[9]; stimulus row p[4] with remainder p[5] (units of
    # 1e-9 row), advancing p[6] per conversion; p[3] columns, p[7] rows.
    off = p[0]
    mask = p[1]
    n = p[2]
    ncols = p[3]
    row = p[4]
    rem = p[5]
    step = p[6]
    nrows = p[7]
    k = p[8]
    norder = p[9]
    one = 1000000  # 1e-6 row; viper ints are 64-bit on the PC ports that run this board
    half = 16500 * one
    full = 33000 * one
    i = 0
    while i < n:
        col = cols[k]
        if col == 255:  # AIN4, the temperature sensor: ~0.706 V at 27 C
            c = 876
        else:
            # the sensor's voltage between stimulus rows, interpolated: a conversion between
            # rows sees the signal at its own instant, not the row before (held, a scan 16 us
            # before its tick read a value 184 us old). Kept in 1e-6 of the rows' 0.1 mV and
            # rounded once, by the ADC: flooring it to whole 0.1 mV first makes an error that
            # follows the sign of the slope (at a fixed place between rows, +1 row step loses
            # 0.93, -1 loses 0.07), which a fit reads as the channel sampled ~40 us early (Iz
            # -0.26% with a servo lag hidden)
            r = row
            if r >= nrows - 1:
                r = nrows - 1
                v = volts[r * ncols + col] * one
            else:
                v0 = volts[r * ncols + col]
                v1 = volts[(r + 1) * ncols + col]
                v = v0 * one + (v1 - v0) * (rem // 1000)
            c = (v * 4095 + half) // full
            if c > 4095:
                c = 4095
        buf[off] = c & 0xFF
        buf[off + 1] = c >> 8
        off = (off + 2) & mask
        k += 1
        if k == norder:
            k = 0
        rem += step
        while rem >= 1000000000:
            rem -= 1000000000
            row += 1
        i += 1
    return off


class Adc:
    def __init__(self, board):
        self.b = board
        self.cs = 0
        self.fcs = 0
        self.div = 0
        self.running = False
        self.start_ns = 0
        self.conv_ns = 2000
        self.done = 0  # conversions taken since START_MANY
        self.order = bytearray(5)  # AIN of each round-robin step
        self.cols = bytearray(5)  # stimulus column of each step (255: temperature)
        self.norder = 0
        self.fifo_level = 0
        self.dma = None  # the channel paced by DREQ_ADC
        self.p = array("i", [0] * 10)

    # -- registers ----------------------------------------------------------------
    def read(self, addr):
        self.sync()
        if addr == CS:
            return self.cs | 0x100  # READY
        if addr == FCS:
            return self.fcs | (self.fifo_level << 16) | (0x100 if self.fifo_level == 0 else 0)
        if addr == FIFO:
            if self.fifo_level:
                self.fifo_level -= 1
            return 0
        if addr == DIV:
            return self.div
        return 0

    def write(self, addr, v):
        self.sync()
        if addr == CS:
            was = self.running
            self.cs = v & ~0x4
            self.running = bool(v & 8) and bool(v & 1)
            if self.running and not was:
                self._start()
        elif addr == FCS:
            self.fcs = v & 0x0F00000F
        elif addr == DIV:
            self.div = v & 0xFFFFFF
        else:
            raise HwError("ADC register 0x%x is not modelled" % addr)

    def _start(self):
        mask = (self.cs >> 16) & 0x1F
        ain = (self.cs >> 12) & 7
        n = 0
        for _ in range(5):  # AINSEL first, then the next inputs in the mask, cyclically
            if mask == 0 or mask >> ain & 1:
                self.order[n] = ain
                col = self.b.stim.cols.get(26 + ain) if ain < 4 else None
                if ain < 4 and col is None:
                    raise HwError("ADC input %d (GP%d) has no signal in this simulation" % (ain, 26 + ain))
                self.cols[n] = 255 if ain == 4 else col
                n += 1
            if mask == 0:
                break
            ain = (ain + 1) % 5
        self.norder = n
        cycles = 1 + (self.div >> 8) + (self.div & 0xFF) / 256
        if cycles < 96:
            cycles = 96
        self.conv_ns = int(cycles * 1000 / 48 + 0.5)
        self.start_ns = self.b.now * 1000
        self.done = 0

    # -- time ---------------------------------------------------------------------
    def sync(self):
        # Take every conversion that has completed by now.
        if not self.running:
            return
        due = (self.b.now * 1000 - self.start_ns) // self.conv_ns
        n = due - self.done
        if n <= 0:
            return
        d = self.dma
        if not (self.fcs & 1) or d is None or not (self.fcs & 8):
            self._to_fifo(n)
            self.done = due
            return
        while n > 0:
            if not d.active_now:
                self._to_fifo(n)
                break
            take = n if n < d.remaining else d.remaining
            self._dma_take(d, take)  # conversions done .. done + take
            self.done += take
            n -= take
            if d.remaining == 0:
                d.finish()
        self.done = due

    def _to_fifo(self, n):
        if self.fcs & 1:
            room = 4 - self.fifo_level
            if n > room:
                self.fcs |= 0x800  # OVER
                n = room
            self.fifo_level += n

    def _dma_take(self, d, n):
        ring = d.ring_bytes
        per = 2
        keep = n
        first = self.done
        if n * per > ring:  # only the last ring's worth survives
            skip = n - ring // per
            d.off = (d.off + skip * per) & (ring - 1)
            first += skip
            keep = n - skip
        s = self.b.stim
        w = s.volts
        p = self.p
        step = self.conv_ns * s.fs  # 1e-9 rows per conversion
        # conversions per _fill: their rows (and the next, for the interpolation) must fit
        # in the stimulus window (stimfile.py); a DMA ring's worth always does at the defaults
        most = (w.cap - 2) * 1000000000 // step
        if most < 1:
            raise HwError("the stimulus window holds %d rows: too few for one conversion" % w.cap)
        while keep > 0:
            m = keep if keep < most else most
            a = (self.start_ns + first * self.conv_ns) * s.fs
            row = a // 1000000000
            hi = (a + (m - 1) * step) // 1000000000 + 1
            last = s.n_rows - 1
            lo = row if row < last else last
            p[0] = d.off
            p[1] = ring - 1
            p[2] = m
            p[3] = s.n_cols
            p[4] = row - lo + w.cover(lo, hi if hi < last else last)
            p[5] = a % 1000000000
            p[6] = step
            p[7] = s.n_rows - w.base
            p[8] = first % self.norder
            p[9] = self.norder
            d.off = _fill(d.buf, w.buf, p, self.cols)
            first += m
            keep -= m
        d.remaining -= n


class Dma:
    """One claimed channel, with rp2.DMA's interface."""

    def __init__(self, hw, channel):
        self.hw = hw
        self._ch = channel
        self.ctrl = 0
        self.active_now = False
        self.remaining = 0
        self.reload = 0
        self.buf = None
        self.base = 0
        self.off = 0
        self.ring_bytes = 0
        self.read_addr = 0
        self.write_addr = 0
        self.chain = channel
        self.regs = bytearray(64)  # stands in for the channel's register block
        self.regs_addr = _addr(self.regs)
        self.src = None

    @property
    def channel(self):
        return self._ch

    @property
    def registers(self):
        return memoryview(self.regs)

    @staticmethod
    def pack_ctrl(default=None, **kw):
        v = {"enable": 1, "high_pri": 0, "size": 2, "inc_read": 1, "inc_write": 1, "ring_size": 0,
             "ring_sel": 0, "chain_to": None, "treq_sel": _PERMANENT, "irq_quiet": 1, "bswap": 0,
             "sniff_en": 0, "write_err": 0, "read_err": 0}
        for k in kw:
            if k not in v:
                raise ValueError("unknown DMA ctrl field " + k)
        v.update(kw)
        chain = v["chain_to"]
        if chain is None:
            chain = 0xF  # replaced by the channel itself in config()
        return (v["enable"] & 1 | (v["high_pri"] & 1) << 1 | (v["size"] & 3) << 2 | (v["inc_read"] & 1) << 4
                | (v["inc_write"] & 1) << 5 | (v["ring_size"] & 0xF) << 6 | (v["ring_sel"] & 1) << 10
                | (chain & 0xF) << 11 | (v["treq_sel"] & 0x3F) << 15 | (v["irq_quiet"] & 1) << 21
                | (v["bswap"] & 1) << 22 | (v["sniff_en"] & 1) << 23)

    def config(self, read=None, write=None, count=None, ctrl=None, trigger=False):
        adc = self.hw.adc
        adc.sync()
        if ctrl is not None:
            self.ctrl = ctrl
        c = self.ctrl
        self.chain = (c >> 11) & 0xF
        treq = (c >> 15) & 0x3F
        if read is not None:
            self.read_addr = read if isinstance(read, int) else _addr(read)
            self.src = None if isinstance(read, int) else read
        if write is not None:
            self.write_addr = write if isinstance(write, int) else _addr(write)
            self.buf = None if isinstance(write, int) else write
        if count is not None:
            self.reload = count
        if self.read_addr == FIFO:
            if treq != DREQ_ADC:
                raise HwError("a DMA channel reading the ADC FIFO must be paced by DREQ_ADC (%d), not %d"
                              % (DREQ_ADC, treq))
            if c >> 4 & 1:
                raise HwError("the ADC FIFO is one address: inc_read must be False")
            if (c >> 2) & 3 != 1:
                raise HwError("ADC results are half-words: size must be 1")
            ring = 1 << ((c >> 6) & 0xF) if (c >> 6) & 0xF else 0
            if not (c >> 10 & 1) or not ring:
                raise HwError("the ADC channel must write into a ring (ring_sel=True, ring_size)")
            if self.write_addr % ring:
                raise HwError("the DMA write ring of %d bytes must be aligned to %d bytes (address 0x%x)"
                              % (ring, ring, self.write_addr))
            if self.buf is None or len(self.buf) < ring:
                raise HwError("the DMA write ring must be a buffer of at least %d bytes" % ring)
            self.base = self.write_addr
            self.off = 0
            self.ring_bytes = ring
            adc.dma = self
        if trigger:
            self.remaining = self.reload
            self.active_now = True

    def finish(self):
        # count ran out: trigger the chained channel, which must re-arm this one
        self.active_now = False
        if self.chain == self._ch or self.chain == 0xF:
            return
        r = self.hw.dma_ch.get(self.chain)
        if r is None:
            raise HwError("DMA chain_to %d: no such claimed channel" % self.chain)
        if r.write_addr != self.regs_addr + 28 or r.reload != 1 or r.src is None:
            raise HwError("the chained DMA channel must write one word to AL1_TRANS_COUNT_TRIG")
        self.reload = struct.unpack_from("<I", r.src, 0)[0]
        self.remaining = self.reload
        self.active_now = self.reload > 0
        self.hw.reloads += 1

    def active(self, v=None):
        if v is None:
            self.hw.adc.sync()
            return self.active_now
        self.hw.adc.sync()
        self.active_now = bool(v)

    @property
    def count(self):
        self.hw.adc.sync()
        return self.remaining

    @property
    def write(self):
        self.hw.adc.sync()
        return self.base + self.off if self.ring_bytes else self.write_addr

    def close(self):
        self.active_now = False


def _addr(obj):
    import uctypes
    return uctypes.addressof(obj)


class PioProgram:
    def __init__(self, fn, kw):
        self.fn = fn
        self.kw = kw
        self.instr = []
        self.labels = {}
        gl = {}
        names = ("jmp", "wait", "in_", "out", "push", "pull", "mov", "irq", "set", "nop", "label",
                 "wrap_target", "wrap", "word")

        def rec(name):
            def f(*args):
                if name == "label":
                    self.labels[args[0]] = len(self.instr)
                elif name not in ("wrap_target", "wrap"):
                    self.instr.append((name,) + args)
                return self
            return f

        for n in names:
            gl[n] = rec(n)
        for n in ("x", "y", "pins", "pin", "null", "isr", "osr", "pc", "exec", "status", "x_dec", "y_dec",
                  "not_x", "not_y", "x_not_y", "not_osre", "noblock", "block", "iffull", "ifempty",
                  "clear", "rel", "gpio", "pindirs"):
            gl[n] = n
        gl["invert"] = lambda v: ("invert", v)
        gl["reverse"] = lambda v: ("reverse", v)
        g = fn.__globals__
        saved = {k: g[k] for k in gl if k in g}
        g.update(gl)
        try:
            fn()
        finally:
            for k in gl:
                if k in saved:
                    g[k] = saved[k]
                else:
                    del g[k]
        if len(self.instr) > 32:
            raise HwError("PIO program of %d instructions: a PIO block holds 32" % len(self.instr))


class StateMachine:
    """The firmware's pulse counter (servo_pio.pulse_counter) at the level of its FIFO:
    per pulse it pushes X = counter after the rise and Y = counter before the push,
    30 bits each, the counter falling 1 per us from 2^32 - 1 at activation."""

    # cycle-count results (tests/test_board_capture.py checks them on the assembled program)
    RISE_LAG_US = 2  # X = counter at the rise + 2 us (+-0.5: the program's cycle count)
    FALL_LAG_US = 4  # Y = counter at the fall + 4 us

    def __init__(self, hw, sm_id, prog, freq=None, jmp_pin=None, **kw):
        if not isinstance(prog, PioProgram):
            raise HwError("StateMachine needs an @rp2.asm_pio program")
        if freq != 2000000:
            raise HwError("the pulse counter's loops are 2 cycles per us: freq must be 2 MHz")
        if jmp_pin is None:
            raise HwError("the pulse counter tests its input with `jmp pin`: give jmp_pin")
        self.hw = hw
        self.pin = jmp_pin.id
        self.fifo = array("i", [0] * 8)
        self.n = 0
        self.head = 0
        self.lost = 0
        self.start_us = 0
        self.on = False
        self.t_rise = -1
        hw.sm[self.pin] = self

    def active(self, v=None):
        if v is None:
            return self.on
        self.on = bool(v)
        self.start_us = self.hw.b.now
        self.t_rise = -1

    def edge(self, t_us, level):
        if not self.on:
            return
        if level:
            self.t_rise = t_us
            return
        if self.t_rise < 0:
            return
        # counter(t) = 2^32 - 1 - (t - start), sampled 1 us late through the synchroniser
        x = (_MASK32 - (self.t_rise - self.start_us + self.RISE_LAG_US)) & 0x3FFFFFFF
        y = (_MASK32 - (t_us - self.start_us + self.FALL_LAG_US)) & 0x3FFFFFFF
        self._push(x)
        self._push(y)
        self.t_rise = -1

    def _push(self, v):
        if self.n == 8:
            self.lost += 1
            return
        self.fifo[(self.head + self.n) & 7] = v
        self.n += 1

    def rx_fifo(self):
        return self.n

    def get(self, buf=None, shift=0):
        if self.n == 0:
            raise HwError("sm.get() on an empty FIFO blocks for ever")
        v = self.fifo[self.head]
        self.head = (self.head + 1) & 7
        self.n -= 1
        return v >> shift


class Rp2040:
    def __init__(self, board):
        self.b = board
        self.adc = Adc(board)
        self.dma_ch = {}
        self.sm = {}  # jmp pin -> StateMachine
        self.reloads = 0

    def make_sm(self, sm_id, prog, freq, **kw):
        return StateMachine(self, sm_id, prog, freq=freq, **kw)

    def claim_dma(self):
        ch = len(self.dma_ch)
        if ch >= 12:
            raise OSError("no DMA channels free")
        d = Dma(self, ch)
        self.dma_ch[ch] = d
        return d
