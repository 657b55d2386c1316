# The simulated board, for the MicroPython unix port: a virtual clock, ADC pins
# that read a stimulus file written by hil_sim, and pin interrupts fired from its
# edge lists. The firmware cannot tell it from a Pico or an ESP32: `machine.py`
# and `time.py` beside this file shadow the built-ins on MICROPYPATH.
#
# Time is virtual. The firmware's timer callbacks and pin IRQs fire in time
# order whenever the firmware waits (machine.idle, time.sleep_*), or while a
# write is stalled (a host that stopped reading), as interrupts would on the car.
# In real-time mode the clock is paced to the wall clock.
#
# Nothing here may allocate while firing events: the firmware's allocation test
# runs its sampler interrupt under micropython.heap_lock() through this code.
import json
import os
import struct
from array import array

import utime

_MASK30 = 0x3FFFFFFF
_FAR = 1 << 62


class _Stim:
    def __init__(self, path):
        with open(path, "rb") as f:
            if f.read(8) != b"STIDSIM2":
                raise OSError("not a stid stimulus file: " + path)
            (hlen,) = struct.unpack("<I", f.read(4))
            h = json.loads(f.read(hlen))
            self.h = h
            self.board = h["board"]
            self.fs = h["fs_sig"]
            self.n_rows = h["n_rows"]
            self.n_cols = len(h["cols"])
            self.cols = {int(k): v for k, v in h["cols"].items()}
            self.volts = array("H", bytearray(2 * self.n_rows * self.n_cols))
            f.readinto(self.volts)
            self.steer = array("H", bytearray(2 * h["n_steer"]))
            f.readinto(self.steer)
            self.steer_rise = array("I", bytearray(4 * h["n_steer"]))
            f.readinto(self.steer_rise)
            self.hall = array("I", bytearray(4 * h["n_hall"]))
            f.readinto(self.hall)
            self.hall_pin = bytearray(h["n_hall"])  # pin of each hall edge
            f.readinto(self.hall_pin)
        self.duration_us = h["duration_us"]


class Board:
    def __init__(self, path, realtime=False):
        s = _Stim(path)
        self.stim = s
        self.now = 0  # virtual us since start
        self.start_ticks = s.h.get("start_ticks", 0)
        self.realtime = realtime
        self.wall0 = 0
        self.finished = False
        self.timer_due = _FAR
        self.timer_period = 0
        self.timer_cb = None
        self.timer_obj = None
        self.pin_level = {}
        self.irq = {}  # pin number -> (handler, trigger mask, Pin object)
        # steering servo edges: rising at the receiver's times, falling a width later
        self.steer_pin = s.h["steer_pin"]
        self.steer_k = 0
        self.steer_high = False
        self.hall_i = 0
        # every key present up front: a first insert while firing events would allocate
        self.pin_level[self.steer_pin] = 0
        for pin in s.h["hall_pins"]:
            self.pin_level[pin] = 1
        self.stalls = s.h.get("stalls", [])
        self.stall_i = 0
        self.row = -1
        self.adc_esp32 = s.board == "esp32"

    # -- clock --------------------------------------------------------------
    def ticks_us(self):
        return (self.now + self.start_ticks) & _MASK30

    def ticks_ms(self):
        return ((self.now + self.start_ticks) // 1000) & _MASK30

    def _next_steer(self):
        if self.steer_k >= len(self.stim.steer):
            return _FAR
        t = self.stim.steer_rise[self.steer_k]
        if self.steer_high:
            t += self.stim.steer[self.steer_k]
        return t

    def _next_hall(self):
        if self.hall_i >= len(self.stim.hall):
            return _FAR
        return self.stim.hall[self.hall_i]

    def _pace(self, t):
        if self.realtime:
            if self.wall0 == 0:
                self.wall0 = utime.time_ns() // 1000
            lag = t - (utime.time_ns() // 1000 - self.wall0)
            if lag > 200:
                utime.sleep_us(lag)

    def advance_to(self, t_end):
        # Fire every event due up to t_end in time order, then set the clock.
        while True:
            ts = self._next_steer()
            th = self._next_hall()
            tt = self.timer_due
            t = ts
            if th < t:
                t = th
            if tt < t:
                t = tt
            if t > t_end:
                break
            self._pace(t)
            self.now = t
            if t == tt:
                self.timer_due = tt + self.timer_period
                self.timer_cb(self.timer_obj)
            elif t == ts:
                if self.steer_high:
                    self.steer_high = False
                    self.steer_k += 1
                    self._edge(self.steer_pin, 0)
                else:
                    self.steer_high = True
                    self._edge(self.steer_pin, 1)
            else:
                pin = self.stim.hall_pin[self.hall_i]
                self.hall_i += 1
                self._edge(pin, 0)
                self.pin_level[pin] = 1
        if t_end > self.now:
            self._pace(t_end)
            self.now = t_end
        if self.now >= self.stim.duration_us:
            self.finished = True

    def _edge(self, pin_no, level):
        self.pin_level[pin_no] = level
        h = self.irq.get(pin_no)
        if h is not None:
            handler, trig, pin = h
            if (level and trig & 1) or (not level and trig & 2):
                handler(pin)

    def idle(self):
        # Wait for the next interrupt, as machine.idle() does on the car.
        t = self.timer_due
        ts = self._next_steer()
        if ts < t:
            t = ts
        th = self._next_hall()
        if th < t:
            t = th
        if t >= _FAR:
            t = self.now + 1000
        end = self.stim.duration_us
        if t >= end:  # the stimulus covers [0, end): nothing happens at or after it
            self.now = end
            self.finished = True
            return
        self.advance_to(t)

    # -- analog ---------------------------------------------------------------
    def volts_01mv(self, pin_no):
        s = self.stim
        row = self.now * s.fs // 1000000
        if row >= s.n_rows:
            row = s.n_rows - 1
        return s.volts[row * s.n_cols + s.cols[pin_no]]

    def read_u16(self, pin_no):
        v = self.volts_01mv(pin_no)
        c = (v * 4095 + 16500) // 33000  # RP2040: 12 bits over 0..3.3 V
        if c > 4095:
            c = 4095
        return (c << 4) | (c >> 8)  # as rp2's read_u16 scales 12 bits to 16

    def read_uv(self, pin_no):
        v = self.volts_01mv(pin_no)  # ESP32, 11 dB: linear 0.15..2.45 V only
        if v < 1500:
            v = 1500
        if v > 24500:
            v = 24500
        return v * 100

    # -- output with stalls ---------------------------------------------------
    def stall_if_due(self):
        # A host that stops reading blocks the write; interrupts keep firing.
        if self.stall_i < len(self.stalls) and self.now >= self.stalls[self.stall_i][0]:
            d = self.stalls[self.stall_i][1]
            self.stall_i += 1
            self.advance_to(self.now + d)


class Output:
    def __init__(self, board, stream):
        self.board = board
        self._w = stream.write

    def write(self, buf, n=-1):
        self.board.stall_if_due()
        if n < 0:
            return self._w(buf)
        return self._w(buf, n)


BOARD = None


def board():
    global BOARD
    if BOARD is None:
        path = os.getenv("STID_SIM_STIMULUS")
        if not path:
            raise OSError("STID_SIM_STIMULUS is not set: the simulated board needs a stimulus file")
        BOARD = Board(path, realtime=os.getenv("STID_SIM_REALTIME") == "1")
    return BOARD
