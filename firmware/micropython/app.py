# The firmware's main loop: start the sampler, turn the ring into frames, send
# HELLO and STATUS on schedule. Sampling runs in the timer interrupt; this loop
# only moves bytes, so a slow or absent host costs overruns (counted), never
# a late sample.
import json
import os
import sys
import time

import machine
import micropython
from machine import Timer
from micropython import const

import boards
import codec
from pulses import HallCounter, ServoPulse
from ring import SampleRing
from sampler import Sampler

FW_VERSION = "0.2.0"
_MASK30 = const(0x3FFFFFFF)
_STATUS_PERIOD_MS = const(1000)
_STEER_TIMEOUT_US = const(100000)


def _boot_id():
    try:
        return "".join("%02x" % b for b in os.urandom(4))
    except (AttributeError, OSError):
        return "%08x" % (time.ticks_us() & 0xFFFFFFF)


def _compact_json(doc):
    # no blanks after , and : (HELLO is ~15% shorter); ports without `separators`
    # fall back to the default spacing
    try:
        return json.dumps(doc, separators=(",", ":"))
    except TypeError:
        return json.dumps(doc)


class App:
    def __init__(self, board="pico", rate_hz=500, batch=10, ring_size=256, out=None,
                 hello_period_s=2, extra_hello=None, wheels=None, wheel_ppr=None):
        # wheels: None (the board's one hall sensor), 4 (its four), or {position: pin}
        profile, readers = boards.open_channels(board)
        wheel_list = boards.wheel_list(profile, wheels)
        ppr = profile["wheel_ppr"] if wheel_ppr is None else wheel_ppr
        four = len(wheel_list) == 4
        self.ftype = codec.SAMPLES4 if four else codec.SAMPLES
        self.record_size = codec.SAMPLE4_SIZE if four else codec.SAMPLE_SIZE
        most = codec.max_batch(self.record_size)
        if not 1 <= batch <= most:
            raise ValueError("batch must be 1..%d samples per frame" % most)
        if not 10 <= rate_hz <= 5000:
            raise ValueError("rate_hz must be 10..5000")
        if ring_size < 2 * batch:
            raise ValueError("ring_size must hold at least two frames")
        self.profile = profile
        self.rate_hz = rate_hz
        self.batch = batch
        self.steer = ServoPulse(profile["steer_pin"], _STEER_TIMEOUT_US)
        self.wheels = [HallCounter(pin) for _, pin in wheel_list]
        self.wheel = self.wheels[0]
        self.ring = SampleRing(ring_size, self.record_size)
        self.sampler = Sampler(self.ring, readers, self.steer, self.wheels)
        self.enc = codec.FrameEncoder()
        self.out = out if out is not None else sys.stdout.buffer
        self._write = self.out.write
        wl = [{"pin": pin, "pulses_per_rev": ppr, "wheel": pos} for pos, pin in wheel_list]
        doc = {
            "proto": codec.VERSION, "fw": FW_VERSION, "board": board, "boot_id": _boot_id(),
            "rate_hz": rate_hz, "batch": batch, "mod": _MASK30 + 1,
            "adc": profile["adc"], "adc_clip_v": profile["adc_clip_v"],
            "channels": boards.channel_map(profile),
            "steer": {"pin": profile["steer_pin"], "period_us": 20000, "timeout_us": _STEER_TIMEOUT_US},
            "wheel": wl[0], "wheels": wl,
        }
        if extra_hello:
            doc.update(extra_hello)
        self.hello_doc = _compact_json(doc).encode()  # built once: sending it allocates nothing
        if len(self.hello_doc) > codec.MAX_FRAME - 14:
            raise ValueError("HELLO document too long for one frame")
        self.hello_period_ms = hello_period_s * 1000
        self.frames = 0
        self.tx_short = 0
        self._timer = None
        self._t_status = 0
        self._t_hello = 0

    # -- output -------------------------------------------------------------
    def _send(self, n):
        # A USB-CDC port whose host stopped reading accepts part of a write after
        # ~500 ms; the partial frame is caught by the receiver's CRC. Count it.
        w = self._write(self.enc.wire, n)
        if w is not None and w < n:
            self.tx_short += 1
        self.frames += 1

    def send_hello(self):
        self._send(self.enc.hello(time.ticks_us(), self.hello_doc))

    def send_status(self):
        s = self.sampler
        r = self.ring
        self._send(self.enc.status(time.ticks_us(), time.ticks_ms(), s.index, r.overruns,
                                   self.frames, self.tx_short, s.isr_max_us, s.isr_last_us,
                                   r.peak, r.size))
        s.isr_max_us = 0
        r.peak = 0

    def pump(self, flush=False):
        # Send every full batch waiting in the ring (and the partial rest if flushing).
        ring = self.ring
        enc = self.enc
        while True:
            n = ring.run_length(self.batch)
            if n == 0 or (n < self.batch and not flush and ring.fill() < self.batch):
                return
            off = enc.samples_begin(time.ticks_us(), ring.first_index(), n, self.ftype)
            ring.pop_into(enc.raw, off, n)
            self._send(enc.finish(codec.SAMPLES_HEAD + n * self.record_size))

    def service(self):
        now = time.ticks_ms()
        if time.ticks_diff(now, self._t_status) >= _STATUS_PERIOD_MS:
            self._t_status = now
            self.send_status()
        if time.ticks_diff(now, self._t_hello) >= self.hello_period_ms:
            self._t_hello = now
            self.send_hello()

    # -- life cycle ---------------------------------------------------------
    def start(self):
        self._write(b"\x00")  # cleanly delimit the first frame from any boot text
        self._t_status = self._t_hello = time.ticks_ms()
        self.send_hello()
        self._timer = Timer(self.profile["timer_id"])
        try:
            self._timer.init(mode=Timer.PERIODIC, freq=self.rate_hz, callback=self.sampler.isr,
                             hard=self.profile["hard_timer"])
        except TypeError:  # ports whose timers take no `hard` (ESP32: always scheduled)
            self._timer.init(mode=Timer.PERIODIC, freq=self.rate_hz, callback=self.sampler.isr)

    def stop(self):
        if self._timer is not None:
            self._timer.deinit()
            self._timer = None
        self.pump(flush=True)
        self.send_status()

    def run(self, should_stop=None):
        self.start()
        try:
            while should_stop is None or not should_stop():
                self.pump()
                self.service()
                machine.idle()
        finally:
            self.stop()


def main(board=None, **kw):
    try:
        micropython.kbd_intr(-1)  # a 0x03 byte from the host must not be Ctrl-C
    except AttributeError:
        pass
    if hasattr(micropython, "alloc_emergency_exception_buf"):
        micropython.alloc_emergency_exception_buf(100)
    if board is None:
        board = {"rp2": "pico", "esp32": "esp32"}.get(sys.platform, "pico")
    App(board=board, **kw).run()
