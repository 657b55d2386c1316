# The firmware's main loop: start the sampler, turn the ring into frames, send
# HELLO and STATUS on schedule. Sampling runs in the timer interrupt; this loop
# only moves bytes, so a slow or absent host costs overruns (counted), never
# a late sample.
#
# A host that stops reading loses only what the ring cannot hold: a frame's samples
# leave the ring only once its write went through whole. A USB-CDC write the host
# does not take gives up after ~500 ms and returns short (rp2,
# shared/tinyusb/mp_usbd_cdc.c): the samples stay, the next frame starts with a
# delimiter (the part that did go out is one bad frame to the host), and the loop
# goes on to service(), so STATUS, the escape watch and the watchdog are not starved.
#
# It also keeps the board recoverable and alive: it feeds a watchdog only while
# the sampler makes progress (an exception in a hard timer callback stops that
# timer for good on rp2), never on the host's reading, and it watches its input
# for the escape line that `stid flash` sends (ESCAPE), after which the board
# reboots into safe mode so mpremote can reach the REPL (Ctrl-C is disabled while
# the app runs).
import json
import os
import struct
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

FW_VERSION = (0, 3, 3)  # 0.3.3: ESP32 hall by PCNT, servo polled at both edges, 9 min of lost ticks; 0.3.2: issue 22
_MASK30 = const(0x3FFFFFFF)
_STATUS_PERIOD_MS = const(1000)
_COMPACT_HELLO_PERIOD_MS = const(1000)
# a receiver's frame is 20 ms (some 11-22 ms): 50 ms rides out one lost pulse and marks the
# steer stale within 3 frames of the receiver going off (the sampler reads every period)
_STEER_TIMEOUT_US = const(50000)
_HALL_PCNT_UNITS = (2, 3)  # the ESP32's PCNT units of a hall sensor (the servo has 0 and 1)
_WDT_TIMEOUT_MS = const(2000)  # fed before every write, which may block 500 ms; rp2 allows <= 8388 ms
_ESCAPE_POLL_MS = const(100)
_RING_SECONDS_X4 = const(5)  # the default ring holds 1.25 s: a 1 s host stall plus margin
ESCAPE = b"STID-ESCAPE"  # on the input: stop, reboot into safe mode (`stid flash`)
SAFE_BOOT_FILE = "stid_safe_boot"  # main.py: present at boot -> remove it, stay at the REPL
_BOARD_CODES = {"pico": 1, "esp32": 2}
_PART_CODES = {"ADXL335": 1, "LISY300AL": 2, "divider": 3}
_RESET_CODES = {"unknown": 0, "power_on": 1, "hard": 2, "watchdog": 3, "deepsleep": 4, "soft": 5}
_WHEEL_CODES = {"fl": 0, "fr": 1, "rl": 2, "rr": 3}
_LINK_CODES = {"usb": 1, "uart": 2, "pipe": 3}


def _boot_id():
    try:
        return "".join("%02x" % b for b in os.urandom(4))
    except (AttributeError, OSError):
        return "%08x" % (time.ticks_us() & 0xFFFFFFF)


def _micropython_version():
    v = getattr(sys.implementation, "version", (0, 0, 0))
    return (v[0], v[1], v[2])


def bytes_per_sample(record_size, batch):
    # on the wire: the record, plus header (10), samples head (5), CRC (4), COBS code
    # and delimiter (2) shared by the batch; HELLO and STATUS add < 1%
    return record_size + 21 / batch


def compact_hello(doc, timer_hard, sim, mp, uid):
    """The compact binary HELLO body (PROTOCOL.md, HELLO_COMPACT) of a full HELLO doc;
    mp: MicroPython version tuple, uid: machine.unique_id() bytes."""
    ch = doc["channels"]
    parts = []
    for name in ("ax", "ay", "az", "yaw", "vbat"):
        c = ch[name]
        parts.append(0 if c is None else _PART_CODES[c["part"]])
        parts.append(0 if c is None or c["bandwidth_hz"] is None else c["bandwidth_hz"])
    wl = doc["wheels"]
    pos = bytes([_WHEEL_CODES[w["wheel"]] for w in wl] + [0xFF] * (4 - len(wl)))
    link = doc["link"]
    clip = doc["adc_clip_v"]
    cap = doc.get("capture") or {"adc": "cpu", "servo": "irq"}
    body = struct.pack(codec.HELLO_C_FMT, int(doc["boot_id"], 16), _BOARD_CODES.get(doc["board"], 0),
                       (1 if timer_hard else 0) | (2 if sim else 0) | (4 if cap["adc"] == "dma" else 0)
                       | (8 if cap["servo"] == "pio" else 0) | (16 if cap["servo"] == "pcnt" else 0)
                       | (32 if cap.get("hall") == "pcnt" else 0),
                       doc["rate_hz"], doc["batch"],
                       FW_VERSION[0], FW_VERSION[1], FW_VERSION[2], mp[0], mp[1], mp[2],
                       _RESET_CODES.get(doc["reset_cause"], 0), doc["adc"]["bits"],
                       0 if doc["adc"]["unit"] == "count" else 1, int(doc["adc"]["vref"] * 1000 + 0.5),
                       0 if clip is None else int(clip * 1000 + 0.5), *parts,
                       doc["steer"]["period_us"], doc["steer"]["timeout_us"], wl[0]["pulses_per_rev"],
                       len(wl), pos, _LINK_CODES[link["kind"]], link["baud"] or 0,
                       int(link["bytes_per_sample"] * 100 + 0.5), len(uid))
    return body + uid


def _compact_json(doc):
    # no blanks after , and : (HELLO is ~15% shorter); ports without `separators`
    # fall back to the default spacing
    try:
        return json.dumps(doc, separators=(",", ":"))
    except TypeError:
        return json.dumps(doc)


def _open_scan(profile, readers, period_us):
    """(scan, readers, HELLO capture.adc): the RP2040's hardware scan where it runs,
    else the readers that convert on each call ("cpu")."""
    if not profile.get("adc_scan"):
        return None, readers, "cpu"
    import adc_scan
    if adc_scan.unavailable():
        return None, readers, "cpu"
    pins = profile["pins"]
    names = [ch for ch in boards.CHANNELS if pins[ch] is not None]
    scan = adc_scan.AdcScan([pins[ch] - 26 for ch in names], period_us)
    by_name = dict(zip(names, scan.readers()))
    out = [by_name.get(ch, r) for ch, r in zip(boards.CHANNELS, readers)]
    return scan, out, "dma"


def _open_servo(profile):
    """(steering pulse input, HELLO capture.servo): a PIO state machine on the RP2040,
    the pulse counter on the ESP32, else pin interrupts ("irq")."""
    if profile.get("servo_pio"):
        try:
            from servo_pio import ServoPulsePio
            return ServoPulsePio(profile["steer_pin"], _STEER_TIMEOUT_US), "pio"
        except (ImportError, AttributeError):  # no rp2 module / PIO: the pin IRQ below
            pass
    if profile.get("servo_clock_pin") is not None:
        try:
            from servo_pcnt import ServoPulsePcnt
            return ServoPulsePcnt(profile["steer_pin"], _STEER_TIMEOUT_US, profile["servo_clock_pin"]), "pcnt"
        except (ImportError, AttributeError, OSError):  # no esp32.PCNT, or its self-test failed
            pass
    return ServoPulse(profile["steer_pin"], _STEER_TIMEOUT_US), "irq"


def _open_hall_pcnt(profile, wheel_list):
    """One ESP32 hall sensor counted and timed by two pulse-counter units against the servo's
    1 MHz clock (hall_pcnt.py), or None. Set up before the servo starts that clock (see
    hall_pcnt.py). Four sensors would need 8 units beside the servo's 2 (the ESP32 has 8):
    they stay on pin interrupts."""
    if profile.get("servo_clock_pin") is None or len(wheel_list) != 1:
        return None
    try:
        from hall_pcnt import HallCounterPcnt
        return HallCounterPcnt(wheel_list[0][1], profile["servo_clock_pin"], _HALL_PCNT_UNITS)
    except (ImportError, AttributeError, OSError, ValueError):  # no esp32.PCNT, or a unit refused
        return None


class App:
    def __init__(self, board="pico", rate_hz=500, batch=10, ring_size=None, out=None,
                 hello_period_s=10, extra_hello=None, wheels=None, wheel_ppr=None, control=None,
                 watchdog=True):
        # ring_size None: 1.25 s of samples (rides out a 1 s host stall)
        # control: a stream to watch for ESCAPE (None: sys.stdin.buffer on a board)
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
        if not 10 <= rate_hz <= 5000 or 1000000 % rate_hz:
            raise ValueError("rate_hz must be 10..5000 and divide 1000000 (a whole number of us)")
        if ring_size is None:
            ring_size = max(2 * batch, rate_hz * _RING_SECONDS_X4 // 4)
        if ring_size < 2 * batch:
            raise ValueError("ring_size must hold at least two frames")
        self.profile = profile
        self.rate_hz = rate_hz
        self.batch = batch
        period_us = 1000000 // rate_hz
        scan, readers, adc_mode = _open_scan(profile, readers, period_us)
        self.scan = scan
        hall = _open_hall_pcnt(profile, wheel_list)  # before the servo's clock starts
        self.steer, servo_mode = _open_servo(profile)
        if hall is not None and servo_mode != "pcnt":  # no clock (its self-test failed): no low time
            hall.stop()
            hall = None
        hall_mode = "irq" if hall is None else "pcnt"
        self.wheels = [hall] if hall else [HallCounter(pin, profile["hall_debounce_us"]) for _, pin in wheel_list]
        self.wheel = self.wheels[0]
        self.ring = SampleRing(ring_size, self.record_size)
        self.sampler = Sampler(self.ring, readers, self.steer, self.wheels, period_us, scan)
        self.enc = codec.FrameEncoder()
        link = boards.open_link(profile)
        if out is None:
            out = sys.stdout.buffer
        self.out = out
        self._write = self.out.write
        link["bytes_per_sample"] = round(bytes_per_sample(self.record_size, batch), 2)
        wl = [{"pin": pin, "pulses_per_rev": ppr, "wheel": pos} for pos, pin in wheel_list]
        mp = _micropython_version()
        self.hello = {
            "proto": codec.VERSION, "fw": "%d.%d.%d" % FW_VERSION, "board": board, "boot_id": _boot_id(),
            "rate_hz": rate_hz, "batch": batch, "mod": _MASK30 + 1,
            "adc": profile["adc"], "adc_clip_v": profile["adc_clip_v"],
            "channels": boards.channel_map(profile),
            "steer": {"pin": profile["steer_pin"], "period_us": 20000, "timeout_us": _STEER_TIMEOUT_US},
            "wheels": wl,  # version 3 drops `wheel` (= wheels[0]): the host restores it
            "uid": boards.unique_id_hex(), "micropython": "%d.%d.%d" % mp,
            "timer": None, "reset_cause": boards.reset_cause(board), "link": link,
        }
        if adc_mode != "cpu" or servo_mode != "irq":  # absent: both by the CPU, as before 0.3.1
            self.hello["capture"] = {"adc": adc_mode, "servo": servo_mode}
        if hall_mode != "irq":  # (absent: pin interrupts, as before 0.3.3)
            self.hello["capture"]["hall"] = hall_mode
        if extra_hello:
            self.hello.update(extra_hello)
        self.hello_doc = b""  # built at start(), once the timer mode is known
        self.hello_compact = b""
        self.hello_period_ms = hello_period_s * 1000
        self.frames = 0
        self.tx_short = 0
        self._cut = False  # the last write went out short: the next frame starts with a delimiter
        self._timer = None
        self._t_status = 0
        self._t_hello = 0
        self._t_compact = 0
        self._watchdog = watchdog
        self._wdt = None
        self._fed_runs = 0
        self._control = control
        self._poll = None
        self._esc_buf = bytearray(1)
        self._esc_i = 0
        self._t_escape = 0
        self.escaped = False

    # -- output -------------------------------------------------------------
    def _send(self, n):
        # Write the frame in enc.wire; True when it went out whole. A USB-CDC port whose
        # host stopped reading takes part of it (or nothing) after ~500 ms: the part is
        # caught by the receiver's CRC, counted here, and closed by a delimiter before
        # the next frame.
        self.feed_watchdog()  # the write may block ~500 ms
        if self._cut:
            self.sampler.t_free = time.ticks_us()
            w = self._write(b"\x00")
            if w is not None and w < 1:
                self.tx_short = codec.add30(self.tx_short, 1)
                return False
            self._cut = False
        self.sampler.t_free = time.ticks_us()  # the scheduler queue is empty now
        w = self._write(self.enc.wire, n)
        self.frames = codec.add30(self.frames, 1)
        if w is not None and w < n:
            self.tx_short = codec.add30(self.tx_short, 1)
            self._cut = True
            return False
        return True

    def send_hello(self):
        self._send(self.enc.hello(time.ticks_us(), self.hello_doc))

    def send_hello_compact(self):
        self._send(self.enc.hello(time.ticks_us(), self.hello_compact, codec.HELLO_COMPACT))

    def send_status(self):
        s = self.sampler
        r = self.ring
        self._send(self.enc.status(time.ticks_us(), time.ticks_ms(), s.index, r.overruns,
                                   self.frames, self.tx_short, s.isr_max_us, s.isr_last_us,
                                   r.peak, r.size, s.missed, s.late_max_us))
        s.isr_max_us = 0
        s.late_max_us = 0
        r.peak = 0

    def pump(self, flush=False):
        # Send every full batch waiting in the ring (and the partial rest if flushing);
        # stop at a write that did not go out whole: its samples stay in the ring.
        ring = self.ring
        enc = self.enc
        while True:
            n = ring.run_length(self.batch)
            if n == 0 or (n < self.batch and not flush and ring.fill() < self.batch):
                return
            off = enc.samples_begin(time.ticks_us(), ring.first_index(), n, self.ftype)
            ring.copy_into(enc.raw, off, n)
            seq = enc.seq
            if not self._send(enc.finish(codec.SAMPLES_HEAD + n * self.record_size)):
                enc.seq = seq  # sent again under its number: to the host one bad frame, none lost
                return
            ring.release(n)

    def service(self):
        now = time.ticks_ms()
        # while the host does not read (the last write went out short) only pump's retry
        # knocks: each write costs 500 ms, and STATUS counts are cumulative (the next says it)
        if not self._cut:
            if time.ticks_diff(now, self._t_status) >= _STATUS_PERIOD_MS:
                self._t_status = now
                self.send_status()
            if time.ticks_diff(now, self._t_compact) >= _COMPACT_HELLO_PERIOD_MS:
                self._t_compact = now
                self.send_hello_compact()
            if time.ticks_diff(now, self._t_hello) >= self.hello_period_ms:
                self._t_hello = now
                self.send_hello()
        self.feed_watchdog()
        if self._poll is not None and time.ticks_diff(now, self._t_escape) >= _ESCAPE_POLL_MS:
            self._t_escape = now
            self.check_escape()

    def feed_watchdog(self):
        # Fed only while the sampler takes samples: a dead timer (an exception in its
        # callback) resets the board instead of streaming STATUS without samples.
        runs = self.sampler.runs
        if self._wdt is not None and runs != self._fed_runs:
            self._fed_runs = runs
            self._wdt.feed()

    def check_escape(self):
        # Bytes on the input, matched against ESCAPE one at a time (no allocation).
        buf = self._esc_buf
        while self._poll_ready():
            if self._control.readinto(buf) != 1:
                self._poll = None  # end of input (a closed pipe): nothing more to watch
                return
            if buf[0] == ESCAPE[self._esc_i]:
                self._esc_i += 1
                if self._esc_i == len(ESCAPE):
                    self.escaped = True
                    return
            else:
                self._esc_i = 1 if buf[0] == ESCAPE[0] else 0

    def _poll_ready(self):
        for _ in self._poll.ipoll(0):
            return True
        return False

    # -- life cycle ---------------------------------------------------------
    def start(self):
        self._write(b"\x00")  # cleanly delimit the first frame from any boot text
        self._timer = Timer(self.profile["timer_id"])
        hard = self.profile["hard_timer"]
        self.sampler.arm(time.ticks_us())
        try:
            self._timer.init(mode=Timer.PERIODIC, freq=self.rate_hz, callback=self.sampler.isr, hard=hard)
        except (TypeError, ValueError):
            # rp2 before MicroPython 1.26 has no `hard` (TypeError); ESP32 refuses
            # hard=True (ValueError): a scheduled timer, and HELLO says so
            hard = False
            self.sampler.arm(time.ticks_us())
            self._timer.init(mode=Timer.PERIODIC, freq=self.rate_hz, callback=self.sampler.isr)
        self.hello["timer"] = "hard" if hard else "soft"
        sim = bool(self.hello.get("sim"))
        self.hello_doc = _compact_json(self.hello).encode()  # built once: sending it allocates nothing
        if len(self.hello_doc) > codec.MAX_FRAME - 14:
            raise ValueError("HELLO document too long for one frame")
        self.hello_compact = compact_hello(self.hello, hard, sim, _micropython_version(), boards.unique_id())
        self._t_status = self._t_hello = self._t_compact = self._t_escape = time.ticks_ms()
        self.send_hello()
        self.send_hello_compact()
        if self._watchdog:
            try:
                self._wdt = machine.WDT(timeout=_WDT_TIMEOUT_MS)
            except (AttributeError, ValueError):
                self._wdt = None
        self._open_control()

    def _open_control(self):
        ctl = self._control
        if ctl is None:
            return
        try:
            import select
            self._poll = select.poll()
            self._poll.register(ctl, select.POLLIN)
            # ipoll allocates its result tuple on the first call (extmod/modselect.c,
            # poll_ipoll): make that call now, so the main loop's never allocates
            self._poll_ready()
        except (ImportError, AttributeError, OSError):
            self._poll = None

    def stop(self):
        if self._timer is not None:
            self._timer.deinit()
            self._timer = None
        if self.scan is not None:
            self.scan.stop()
        if hasattr(self.steer, "stop"):
            self.steer.stop()
        self.pump(flush=True)
        self.send_status()

    def run(self, should_stop=None):
        self.start()
        try:
            while not self.escaped and (should_stop is None or not should_stop()):
                self.pump()
                self.service()
                self.sampler.t_free = time.ticks_us()  # running bytecode: the queue is empty
                machine.idle()
        finally:
            self.stop()


def safe_boot_requested(profile):
    """main.py asks before starting: the escape file, or the safe pin held low."""
    try:
        os.remove(SAFE_BOOT_FILE)
        return "escape"
    except OSError:
        pass
    pin = profile.get("safe_pin")
    if pin is not None and machine.Pin(pin, machine.Pin.IN, machine.Pin.PULL_UP).value() == 0:
        return "pin"
    return None


def _reboot_to_safe_mode():
    # The watchdog cannot be stopped once started (rp2, ESP32): a reset clears it,
    # and the file tells main.py not to start the app on the way up.
    with open(SAFE_BOOT_FILE, "w") as f:
        f.write("1")
    machine.reset()


def default_board():
    return {"rp2": "pico", "esp32": "esp32"}.get(sys.platform, "pico")


def main(board=None, **kw):
    if board is None:
        board = default_board()
    try:
        micropython.kbd_intr(-1)  # a 0x03 byte from the host must not be Ctrl-C
    except AttributeError:
        pass
    try:
        if hasattr(micropython, "alloc_emergency_exception_buf"):
            micropython.alloc_emergency_exception_buf(100)
        app = App(board=board, control=sys.stdin.buffer, **kw)  # may raise (a bad config.py)
        app.run()
    finally:
        if hasattr(micropython, "kbd_intr"):
            micropython.kbd_intr(3)  # Ctrl-C works again at the REPL
    if app.escaped:
        _reboot_to_safe_mode()
