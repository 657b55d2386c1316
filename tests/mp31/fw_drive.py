# Drive the real firmware (app.App on scripted_board) through a day of driving and
# parking, and check every sample it sends against what the test itself put on the
# pins: the servo pulse in force, every hall edge (bounces excluded), the sample's
# instant on the nominal grid. Interrupts and the main loop run with the heap locked.
#
# The car is written here from plain rules, not from the project's simulator: servo
# pulses every 20 ms (or `servo_period_us`: surface receivers send 91-333 Hz frames;
# widths 1000..1999 us, a fixed pattern), hall edges every 6-11 ms, the line low for 5% of
# the interval after each (the magnet passing),
# while driving with a contact bounce 40 us after every fifth, none while parked; the
# receiver is off while parked (no servo pulses at all).
#
# usage (from a script): d = Drive("pico", start_ticks=...); d.run(plan); d.report()
import micropython

import scripted_board

MASK30 = 0x3FFFFFFF
SERVO_PERIOD_US = 20000


def steer_stale_limit_us(servo_period_us):
    # the promise: stale within 3 servo periods of 20 ms; faster frames keep the firmware's
    # 50 ms timeout (one lost pulse must not read as the receiver off), so within 60 ms
    return max(3 * servo_period_us, 60000)

_BOUNCE_US = 40  # a bounce: the line high again for _GLITCH_US, 40 us after the edge
_GLITCH_US = 5  # (shorter than the ESP32 PCNT's 12.8 us filter; pin IRQs see it)
_DWELL_X1000 = 50  # the line low for 5% of the interval after each edge


class Sink:
    """The serial port: takes every frame, and files the records of sample frames (read
    from the encoder's raw frame, under the heap lock: into preallocated arrays)."""

    def __init__(self, cap):
        from array import array

        self.app = None
        self.cap = cap
        self.n = 0
        self.overflow = 0
        self.idx = array("i", [0] * cap)
        self.t = array("i", [0] * cap)
        self.ax = array("i", [0] * cap)
        self.steer = array("i", [0] * cap)
        self.steer_t = array("i", [0] * cap)
        self.count = array("i", [0] * cap)
        self.wheel_t = array("i", [0] * cap)
        self.bytes = 0

    def write(self, buf, n=-1):
        if n < 0:
            n = len(buf)
        self.bytes += n
        raw = self.app.enc.raw
        if raw[1] != 2:  # only one-wheel SAMPLES frames are checked
            return n
        first = raw[10] | (raw[11] << 8) | (raw[12] << 16) | (raw[13] << 24)
        k = 0
        off = 15
        while k < raw[14]:
            if self.n == self.cap:
                self.overflow += 1
                return n
            j = self.n
            room = MASK30 - first  # (first + k) mod 2^30, never forming 2^30
            self.idx[j] = first + k if k <= room else k - room - 1
            self.t[j] = raw[off] | (raw[off + 1] << 8) | (raw[off + 2] << 16) | (raw[off + 3] << 24)
            self.ax[j] = raw[off + 4] | (raw[off + 5] << 8)
            self.steer[j] = raw[off + 12] | (raw[off + 13] << 8)
            self.count[j] = raw[off + 14] | (raw[off + 15] << 8)
            self.wheel_t[j] = raw[off + 16] | (raw[off + 17] << 8) | (raw[off + 18] << 16) | (raw[off + 19] << 24)
            self.steer_t[j] = raw[off + 22] | (raw[off + 23] << 8) | (raw[off + 24] << 16) | (raw[off + 25] << 24)
            self.n += 1
            off += 26
            k += 1
        return n


def _main_loop(fw):
    # one pass of App.run's loop, heap locked; its exception or None
    micropython.heap_lock()
    try:
        fw.pump()
        fw.service()
        e = None
    except Exception as x:  # noqa: BLE001
        e = x
    micropython.heap_unlock()
    return e


class Drive:
    def __init__(self, board, start_ticks=0, pio=True, dma=True, pcnt=True, rate=500, counters_near_wrap=True,
                 servo_period_us=SERVO_PERIOD_US):
        self.b = scripted_board.new_board(board, start_ticks=start_ticks, pio=pio, dma=dma, pcnt=pcnt)
        import app

        self.sink = Sink(4 * rate)
        self.fw = app.App(board=board, rate_hz=rate, batch=10, out=self.sink)
        self.sink.app = self.fw
        self.period = 1000000 // rate
        self.steer_pin = self.fw.profile["steer_pin"]
        self.hall_pin = self.fw.wheel.pin.id
        self.scan = self.fw.scan
        self.timeout_us = self.fw.steer.timeout_us
        if counters_near_wrap:  # the firmware's own counters cross 2^30 within the run too
            s = self.fw.sampler
            s.index = s.runs = MASK30 - 2 * rate
            self.fw.ring.head = self.fw.ring.tail = MASK30 - 3 * rate
            self.fw.enc.seq = MASK30 - rate // 5
        self.fw.start()
        self.first_tick = self.b.timer_due
        self.idx0 = self.fw.sampler.index
        # the car's truth
        self.servo_period = servo_period_us
        self.next_rise = 3000  # servo pulse k rises at 3000 + servo_period k
        self.k_pulse = 0
        self.pulse_rise = 0  # abs us of the pulse under way: its rise, width and fall (-1: none)
        self.pulse_w = 0
        self.pulse_fall = -1
        self.next_edge = -1  # abs us of the next hall edge, -1: none (parked)
        self.k_edge = 0
        self.bounce_at = -1
        self.hall_up_at = -1  # abs us when the hall line goes high again (-1: it is high)
        self.glitch_end_at = -1  # abs us when a bounce's glitch ends
        self.rx_on = True
        self.driving = False
        self.pulses = []  # (fall, width) not yet passed by a sample
        self.edges = []  # hall edge times not yet passed by a sample
        # what the samples showed
        self.cur_pulse = None  # (fall, width) in force
        self.n_edges_passed = 0
        self.last_edge = -1
        self.samples = 0
        self.bad = {}  # check -> count
        self.first_bad = {}
        self.prev_t_abs = None
        self.prev_idx = None
        self.prev_count = None
        self.count_back = 0
        self.stale_worst_us = 0
        self.wdt_resets = 0
        self.loop_errors = 0
        self.last_fall_before_off = -1
        self.stale_seen = True
        self.edges_fired = 0
        self.bounces_fired = 0
        self.pulses_fired = 0

    # -- the car ------------------------------------------------------------------
    def _hall_interval(self):
        # 6-11 ms: 1.7-3 m/s on a 1:8 wheel with one magnet, a varying pattern
        return 6000 + (self.k_edge * 7919) % 5000

    def set_state(self, driving, rx_on):
        b = self.b
        if driving and not self.driving:
            self.next_edge = b.abs_us + self._hall_interval()
        if not driving:
            self.next_edge = -1
        if rx_on and not self.rx_on:
            k = (b.abs_us - 3000) // self.servo_period + 1
            self.k_pulse = k
            self.next_rise = 3000 + self.servo_period * k
            self.stale_seen = True
        if not rx_on and self.rx_on:
            self.next_rise = -1
            self.stale_seen = False
            self.last_fall_before_off = self.pulse_fall if self.pulse_fall >= 0 else self._last_fall()
        self.driving = driving
        self.rx_on = rx_on

    def _last_fall(self):
        return self.pulses[-1][0] if self.pulses else (self.cur_pulse[0] if self.cur_pulse else -1)

    def _fire_until(self, t_end):
        # every pin edge before t_end, in time order
        b = self.b
        while True:
            t = t_end
            which = 0
            if 0 <= self.next_rise < t:
                t, which = self.next_rise, 1
            if 0 <= self.pulse_fall < t:
                t, which = self.pulse_fall, 2
            if 0 <= self.next_edge < t:
                t, which = self.next_edge, 3
            if 0 <= self.bounce_at < t:
                t, which = self.bounce_at, 4
            if 0 <= self.hall_up_at < t:
                t, which = self.hall_up_at, 5
            if 0 <= self.glitch_end_at < t:
                t, which = self.glitch_end_at, 6
            if which == 0:
                return
            b.advance_to(t)
            if which == 1:
                w = 1000 + (self.k_pulse * 37) % 1000
                self.pulse_fall = t + w
                self.pulse_w = w
                self.pulse_rise = t
                b.fire_pin(self.steer_pin, 1)
                self.k_pulse += 1
                self.next_rise = 3000 + self.servo_period * self.k_pulse if self.rx_on else -1
            elif which == 2:
                b.fire_pin(self.steer_pin, 0)
                b.pio_pulse(self.pulse_rise, t)
                self.pulses.append((t, self.pulse_w))
                self.pulse_fall = -1
                self.pulses_fired += 1
            elif which == 3:
                b.fire_pin(self.hall_pin, 0)
                self.edges.append(t)
                self.edges_fired += 1
                if self.k_edge % 5 == 4:
                    self.bounce_at = t + _BOUNCE_US
                self.k_edge += 1
                gap = self._hall_interval()
                self.hall_up_at = t + gap * _DWELL_X1000 // 1000
                self.next_edge = t + gap if self.driving else -1
            elif which == 4:
                b.glitch(self.hall_pin, 1, _GLITCH_US)
                self.bounce_at = -1
                self.glitch_end_at = t + _GLITCH_US
                self.bounces_fired += 1
            elif which == 5:
                b.fire_pin(self.hall_pin, 1)
                self.hall_up_at = -1
            else:
                b.glitch_end(self.hall_pin, 0)
                self.glitch_end_at = -1

    # -- running ------------------------------------------------------------------------
    def run_for(self, seconds):
        # one main-loop pass per timer period (after the tick), as App.run's loop spins
        b = self.b
        end = b.abs_us + int(seconds * 1000000)
        fw = self.fw
        step = self.first_tick + ((b.abs_us - self.first_tick) // self.period + 1) * self.period
        while step <= end and not self.wdt_resets:
            self._fire_until(step)
            b.advance_to(step)
            if b.timer_due == step:
                if self.scan is not None:
                    b.dma_fill(self.scan)
                b.fire_timer()
            e = _main_loop(fw)
            if e is not None:
                self.loop_errors += 1
                b.last_error = e
            if b.wdt_expired():  # the board resets: this run of the firmware is over
                self.wdt_resets += 1
            if self.sink.n:
                self._check_samples()
            step += self.period
        self._fire_until(end)
        b.advance_to(end)

    def _bad(self, what, detail):
        self.bad[what] = self.bad.get(what, 0) + 1
        if what not in self.first_bad:
            self.first_bad[what] = detail

    def _check_samples(self):
        s = self.sink
        for j in range(s.n):
            self._check_one(s.idx[j], s.t[j], s.ax[j], s.steer[j], s.steer_t[j], s.count[j], s.wheel_t[j])
        s.n = 0

    def _ticks(self, abs_us):
        # ticks_us at board time abs_us
        return (self.b.start_ticks + abs_us) & MASK30

    def _check_one(self, idx, t, ax, steer, steer_t, count, wheel_t):
        self.samples += 1
        # index continuity: no sample missed or dropped
        if self.prev_idx is not None and idx != (self.prev_idx + 1) & MASK30:
            self._bad("index gap", (self.prev_idx, idx))
        self.prev_idx = idx
        # the sample's instant: its tick (or, with the ADC scan, the scan before it)
        k = (idx - self.idx0) & MASK30
        tick_abs = self.first_tick + k * self.period
        if self.prev_t_abs is None:
            d = (self._ticks(tick_abs) - t) & MASK30 if self.scan is not None else 0
            t_abs = tick_abs - d
        else:
            dt = ((t - self._ticks(self.prev_t_abs) + 0x20000000) & MASK30) - 0x20000000
            t_abs = self.prev_t_abs + dt
        self.prev_t_abs = t_abs
        if self._ticks(t_abs) != t:
            self._bad("time", (idx, t, t_abs))
        if self.scan is None:
            if t_abs != tick_abs:
                self._bad("time off its tick", (idx, t_abs, tick_abs))
        else:
            su = self.b.scan_us
            back = tick_abs - t_abs
            scan_k = (t_abs - self.b.scan_t0_abs) // su
            if not su <= back <= 4 * su or (t_abs - self.b.scan_t0_abs) % su:
                self._bad("scan instant", (idx, back))
            if (scan_k & 0xFFF) != ax:
                self._bad("scan latched", (idx, scan_k & 0xFFF, ax))
        # servo: the latest pulse that fell before the instant, stale after the timeout
        while self.pulses and self.pulses[0][0] < t_abs:
            self.cur_pulse = self.pulses.pop(0)
        want, want_t = 0, None
        if self.cur_pulse is not None:
            fall, w = self.cur_pulse
            want_t = self._ticks(fall)
            if t_abs - fall <= self.timeout_us:
                want = w
        if steer != want or (want and steer_t != want_t):
            self._bad("steer", (idx, t_abs, steer, want, steer_t, want_t))
        if not self.rx_on and not self.stale_seen and steer == 0 and self.last_fall_before_off >= 0:
            self.stale_seen = True
            late = t_abs - self.last_fall_before_off
            if late > self.stale_worst_us:
                self.stale_worst_us = late
        # hall: every edge before the instant, none after; bounces never
        while self.edges and self.edges[0] < t_abs:
            self.last_edge = self.edges.pop(0)
            self.n_edges_passed += 1
        if count != self.n_edges_passed & 0xFFFF:
            self._bad("hall count", (idx, t_abs, count, self.n_edges_passed & 0xFFFF))
        if self.last_edge >= 0 and wheel_t != self._ticks(self.last_edge):
            self._bad("hall edge time", (idx, wheel_t, self._ticks(self.last_edge)))
        if self.prev_count is not None and ((count - self.prev_count) & 0xFFFF) > 0x8000:
            self.count_back += 1
        self.prev_count = count

    def run(self, plan, say=None):
        """plan: [(label, seconds, driving, receiver_on), ...]"""
        for label, seconds, driving, rx_on in plan:
            self.set_state(driving, rx_on)
            self.run_for(seconds)
            if say:
                say("%s %d s: %d samples, errors %d/%d/%d" % (label, seconds, self.samples, self.b.isr_errors,
                                                             self.b.hard_edge_errors, self.loop_errors))

    def totals(self):
        fw = self.fw
        return {
            "samples": self.samples,
            "isr_errors": self.b.isr_errors,
            "pin_irq_errors": self.b.hard_edge_errors,
            "main_loop_errors": self.loop_errors,
            "last_error": repr(self.b.last_error) if self.b.last_error is not None else None,
            "watchdog_resets": self.wdt_resets,
            "missed": fw.sampler.missed,
            "overruns": fw.ring.overruns,
            "bad": self.bad,
            "first_bad": self.first_bad,
            "count_steps_back": self.count_back,
            "edges": self.edges_fired,
            "bounces": self.bounces_fired,
            "hall_count": fw.wheel.count,
            "pulses": self.pulses_fired,
            "stale_worst_us": self.stale_worst_us,
            "sink_overflow": self.sink.overflow,
            "capture": (self.scan is not None, type(fw.steer).__name__, self.b.timer_hard, type(fw.wheel).__name__),
        }
