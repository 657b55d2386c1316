# The simulated board, for the MicroPython unix port: a virtual clock, ADC pins
# that read a stimulus file written by hil_sim, and pin interrupts fired from its
# edge lists. The firmware cannot tell it from a Pico or an ESP32: `machine.py`
# and `time.py` beside this file shadow the built-ins on MICROPYPATH.
#
# Time is virtual. The firmware's timer callbacks and pin IRQs fire in time
# order whenever the firmware waits (machine.idle, time.sleep_*), or while a
# write is blocked, as interrupts would on the car. In real-time mode the clock
# is paced to the wall clock.
#
# What the boards do, from the MicroPython sources (firmware/README.md cites them):
# - Soft timers (ESP32 always; rp2 before 1.26 or with hard=False) only schedule
#   their callback (mp_sched_schedule). The queue holds MICROPY_SCHEDULER_DEPTH = 8
#   entries; a tick that finds it full is lost without a trace. Queued callbacks run
#   when the VM is between bytecodes: here, when a wait or a write returns.
# - Pin IRQs on the ESP32 are scheduled too (ports/esp32/machine_pin.c,
#   machine_pin_isr_handler: mp_sched_schedule, and Pin.irq takes no `hard`): each
#   edge takes a place in the same 8-deep queue as the timer, in arrival order, and
#   its handler runs when the VM gets to it, reading the pin as it is then. rp2 pin
#   IRQs are hard when asked (hard=True) and scheduled otherwise.
# - Output has the link's throughput: a write blocks until all but the TX buffer
#   has left at the declared baud (ESP32 console UART: 115200 unless the firmware
#   changes it; rp2 USB-CDC: ~1 MB/s). Hard interrupts fire during the block;
#   soft ones queue.
# - Ticks wrap at 2^30 (time.py's ticks_diff and ticks_add behave as a board's).
# - A hard ISR runs for `isr_us`; a pin edge during it is handled after it (the
#   RP2040 gives pin and timer IRQs one priority), so its timestamp is late.
# - A hard interrupt (rp2's hard timer and pin IRQs) runs with the heap locked, as
#   on the board: an allocation in it is a MemoryError.
# - An exception in a hard timer callback stops that timer for good (rp2
#   alarm_callback); a machine.WDT not fed within its timeout resets the board
#   (WatchdogReset; run_firmware.py boots the firmware again).
# - A USB-CDC write whose host has stopped reading puts what fits in the 256-byte
#   FIFO, waits 500 ms for room, and returns the count it took, short or 0
#   (shared/tinyusb/mp_usbd_cdc.c, MICROPY_HW_USB_CDC_TX_TIMEOUT). On a UART the
#   bridge drops what the host does not read; the write goes on.
# - A hall sensor (open collector) pulls its line low while the magnet passes: from each
#   edge for a fraction `hall_dwell` of the interval since that sensor's previous edge
#   (the magnet's arc over the wheel's turn; 300 us for the first), then high again.
#   Pin IRQs on the falling edge see only the fall; a pulse counter gated by the line
#   counts its low time.
# - Reset cause: rp2 reads WDT_RESET after machine.reset() too; the pico-sdk leaves
#   watchdog scratch 4 = 0 after machine.reset(), its magic after machine.WDT
#   (wdt_scratch4, through machine.mem32).
#
# - On a Pico, the RP2040 peripherals the firmware programs directly (ADC registers
#   through machine.mem32, rp2.DMA, a PIO state machine) are modelled in
#   rp2040_hw.py; the PIO sees the servo edges at their true times, unlike IRQs.
#   On an ESP32, the pulse counters and the PWM (esp32.PCNT, machine.PWM) are in
#   esp32_hw.py: they count the edges at their true times.
#
# Nothing here may allocate while firing events: the firmware's allocation test
# runs its sampler interrupt under micropython.heap_lock() through this code.
import json
import os

import micropython
import utime

import esp32_hw
import rp2040_hw
import stimfile

_MASK30 = 0x3FFFFFFF
_FAR = 1 << 62
_TIMER = -1  # a scheduler queue entry for the timer callback (others are pin numbers)
# per board: the console link at power-on (baud None: USB-CDC, ~1 MB/s), its TX
# buffer, the scheduler depth, the MicroPython version the board runs
_BOARDS = {
    "pico": {"baud": None, "tx_buf": 256, "sched_depth": 8, "micropython": [1, 26, 0], "isr_us": 0},
    "esp32": {"baud": 115200, "tx_buf": 128, "sched_depth": 8, "micropython": [1, 26, 0], "isr_us": 0},
}
_USB_BYTE_NS = 1000  # USB full speed CDC moves ~1 MB/s in practice (7-9 Mbit/s)
_USB_TX_TIMEOUT_US = 500000  # MICROPY_HW_USB_CDC_TX_TIMEOUT (ports/rp2/mphalport.h)
RESET_CAUSES = {"power_on": 1, "hard": 2, "watchdog": 3, "deepsleep": 4, "soft": 5}


class WatchdogReset(Exception):
    pass


class MachineReset(Exception):
    # machine.reset(): the firmware asked for it
    pass


WDT_NON_REBOOT_MAGIC = 0x6AB73121  # pico-sdk watchdog_enable -> watchdog scratch 4


class Board:
    def __init__(self, path, realtime=False):
        # board behaviour; STID_SIM_BOARD (JSON) overrides the defaults in _BOARDS
        extra = os.getenv("STID_SIM_BOARD")
        extra = json.loads(extra) if extra else {}
        s = stimfile.Stim(path, rows=extra.get("stim_rows"))
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
        self.irq = {}  # pin number -> (handler, trigger mask, Pin object, hard)
        # steering servo edges: rising at the receiver's times, falling a width later
        self.steer_pin = s.h["steer_pin"]
        self.steer_k = 0
        self.steer_high = False
        self.hall_i = 0
        # the next edge of each, kept up to date as they fire (looked up once per edge,
        # not on every pass of the event loop: the stimulus is read through a window)
        self.t_steer = self._next_steer()
        self.t_hall = self._next_hall()
        # every key present up front: a first insert while firing events would allocate
        self.pin_level[self.steer_pin] = 0
        for pin in s.h["hall_pins"]:
            self.pin_level[pin] = 1
        # each hall line's return to high (a preallocated slot per sensor: no allocation later)
        self.hall_pins = list(s.h["hall_pins"])
        self.hall_rise = [_FAR] * len(self.hall_pins)
        self.hall_prev = [-1] * len(self.hall_pins)  # the sensor's previous edge [us]
        self.t_hall_rise = _FAR
        self.stalls = s.h.get("stalls", [])
        self.stall_i = 0
        self.row = -1
        self.adc_esp32 = s.board == "esp32"
        opts = dict(_BOARDS[s.board])
        opts.update(extra)
        self.opts = opts
        self.hall_dwell_x1000 = int(opts.get("hall_dwell", 0.05) * 1000)
        self.micropython = tuple(opts["micropython"])
        self.set_baud(opts["baud"])
        self.tx_buf = opts["tx_buf"]
        self.tx_idle_ns = 0  # virtual time [ns] when the TX line has sent everything
        self.tx_bytes = 0
        self.sched_depth = opts["sched_depth"]
        self.timer_soft = False
        # the scheduler queue (py/scheduler.c): a ring of entries in arrival order, each
        # _TIMER or the pin number of a scheduled pin IRQ
        self.sched_q = [0] * self.sched_depth
        self.sched_i = 0  # oldest entry
        self.sched_n = 0  # entries waiting
        self.sched_lost = 0  # timer ticks that found the queue full (the truth a test checks)
        self.sched_lost_pin = 0  # pin edges whose callback found the queue full
        self.isr_us = opts["isr_us"]
        self.busy_until = 0  # a hard ISR runs until then; pin edges wait
        self.adc_fault_at = opts.get("adc_fault_at_us", _FAR)  # one ADC read raises then
        # the hard timer's callback fails once then (a fault not modelled otherwise): rp2 stops it
        self.timer_fault_at = opts.get("timer_fault_at_us", s.h.get("timer_fault_us") or _FAR)
        self.timer_dead = False
        self.wdt_timeout = 0
        self.wdt_fed = 0
        self.resets = 0
        self.resetting = False
        self.reset_cause = RESET_CAUSES["power_on"]
        self.wdt_scratch4 = 0  # RP2040 watchdog scratch register 4: kept by a reset
        self.isr_errors = 0  # exceptions raised in hard interrupts (MemoryError: an allocation)
        self.usb_fifo_free = self.tx_buf  # room in the USB-CDC TX FIFO while the host does not read
        # machine.unique_id(): the RP2040's flash id is 8 bytes, the ESP32's MAC 6
        self.rp2040 = rp2040_hw.Rp2040(self) if s.board == "pico" else None
        self.esp32 = esp32_hw.Esp32(self) if s.board == "esp32" else None
        self.uid = bytes(opts.get("uid", [0xE6, 0x60, 0x38, 0xB7, 0x13, 0x3A, 0x2B, 0x2F]))[:8 if s.board == "pico" else 6]

    def set_baud(self, baud):
        self.baud = baud
        self.byte_ns = _USB_BYTE_NS if baud is None else 10000000000 // baud  # start + 8 + stop bits

    # -- clock --------------------------------------------------------------
    def ticks_us(self):
        return (self.now + self.start_ticks) & _MASK30

    def ticks_ms(self):
        return ((self.now + self.start_ticks) // 1000) & _MASK30

    # -- interrupts -----------------------------------------------------------
    def _schedule(self, entry):
        # mp_sched_schedule: queue it, or lose it (False) when the queue is full
        if self.sched_n >= self.sched_depth:
            return False
        self.sched_q[(self.sched_i + self.sched_n) % self.sched_depth] = entry
        self.sched_n += 1
        return True

    def _timer_fires(self):
        if self.timer_soft:
            if not self._schedule(_TIMER):
                self.sched_lost += 1
            return
        self._hw_sync()
        if self.now >= self.timer_fault_at:
            self.timer_fault_at = _FAR
            e = RuntimeError("simboard: injected fault in the timer callback")
        else:
            e = self._hard_irq(self.timer_cb, self.timer_obj)
        if e is not None:  # rp2: "Uncaught exception; don't run the callback again"
            import sys
            sys.print_exception(e)
            self.timer_due = _FAR
            self.timer_dead = True
        self.busy_until = self.now + self.isr_us

    def _hard_irq(self, handler, arg):
        # a hard interrupt: the heap is locked while it runs; its exception, or None
        micropython.heap_lock()
        try:
            handler(arg)
            e = None
        except Exception as x:  # noqa: BLE001 - whatever the board would catch
            e = x
        micropython.heap_unlock()
        if e is not None:
            self.isr_errors += 1
        return e

    def run_scheduled(self):
        # The VM is between bytecodes: run the queued callbacks in arrival order, each
        # at the time it actually runs (late); an exception is printed and forgotten.
        while self.sched_n > 0:
            entry = self.sched_q[self.sched_i]
            self.sched_i = (self.sched_i + 1) % self.sched_depth
            self.sched_n -= 1
            self._hw_sync()
            try:
                if entry == _TIMER:
                    if self.timer_cb is not None:
                        self.timer_cb(self.timer_obj)
                else:
                    h = self.irq.get(entry)
                    if h is not None:
                        h[0](h[2])
            except Exception as e:
                import sys
                sys.print_exception(e)

    def _hw_sync(self):
        # peripherals that run on their own clock catch up before the CPU looks
        if self.rp2040 is not None:
            self.rp2040.adc.sync()

    def _check_wdt(self):
        if self.wdt_timeout and self.now - self.wdt_fed > self.wdt_timeout:
            # from here until reboot() the chip is resetting: no interrupts, no output
            self.wdt_timeout = 0
            self.resetting = True
            self.timer_due = _FAR
            self.timer_cb = None
            self.sched_n = 0
            raise WatchdogReset()

    def reboot(self, cause):
        # What survives a reset: the clock and the stimulus. Interrupts, timers and
        # the scheduler queue are gone.
        self.resets += 1
        self.resetting = False
        self.reset_cause = RESET_CAUSES[cause]
        self.timer_due = _FAR
        self.timer_cb = None
        self.timer_soft = False
        self.timer_dead = False
        self.sched_n = 0
        self.wdt_timeout = 0
        self.irq.clear()
        if self.rp2040 is not None:  # a reset stops the ADC, DMA and PIO
            self.rp2040 = rp2040_hw.Rp2040(self)
        if self.esp32 is not None:  # and the PWM and pulse counters
            self.esp32 = esp32_hw.Esp32(self)

    def _next_steer(self):
        if self.steer_k >= self.stim.n_steer:
            return _FAR
        t = self.stim.steer_rise.at(self.steer_k)
        if self.steer_high:
            t += self.stim.steer.at(self.steer_k)
        return t

    def _hall_fall(self, pin, t):
        # the line goes low at t; back high after the dwell (never past the next edge's time)
        self._edge(pin, 0)
        i = 0
        while self.hall_pins[i] != pin:
            i += 1
        prev = self.hall_prev[i]
        dwell = 300 if prev < 0 else (t - prev) * self.hall_dwell_x1000 // 1000
        if dwell < 1:
            dwell = 1
        self.hall_prev[i] = t
        self.hall_rise[i] = t + dwell
        if t + dwell < self.t_hall_rise:
            self.t_hall_rise = t + dwell

    def _hall_rises(self, t):
        # every hall line due back high at t goes high
        n = len(self.hall_pins)
        nxt = _FAR
        i = 0
        while i < n:
            r = self.hall_rise[i]
            if r <= t:
                self.hall_rise[i] = _FAR
                self._edge(self.hall_pins[i], 1)
            elif r < nxt:
                nxt = r
            i += 1
        self.t_hall_rise = nxt

    def _next_hall(self):
        if self.hall_i >= self.stim.n_hall:
            return _FAR
        return self.stim.hall.at(self.hall_i)

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
            ts = self.t_steer
            th = self.t_hall
            tt = self.timer_due
            tr = self.t_hall_rise
            t = ts
            if th < t:
                t = th
            if tt < t:
                t = tt
            if tr < t:
                t = tr
            if t > t_end:
                break
            self._pace(t)
            self.now = t
            self._check_wdt()
            if t != tt and self.rp2040 is not None and t == ts:
                self._pio_edge(t)  # the state machine samples the pin itself: no IRQ delay
            if t == tt:
                self.timer_due = tt + self.timer_period
                self._timer_fires()
                continue
            if t == tr and t != ts and t != th:  # a hall line back high (nothing triggers on it but a counter)
                self._hall_rises(t)
                continue
            if t < self.busy_until:  # the edge's IRQ waits for the running ISR
                self.now = self.busy_until
            if t == ts:
                if self.steer_high:
                    self.steer_high = False
                    self.steer_k += 1
                    self.t_steer = self._next_steer()
                    self._edge(self.steer_pin, 0)
                else:
                    self.steer_high = True
                    self.t_steer = self._next_steer()
                    self._edge(self.steer_pin, 1)
            else:
                pin = self.stim.hall_pin.at(self.hall_i)
                self.hall_i += 1
                self.t_hall = self._next_hall()
                if self.t_hall_rise <= t:  # a line due back high at this very instant goes first
                    self._hall_rises(t)
                self._hall_fall(pin, t)
        if t_end > self.now:
            self._pace(t_end)
            self.now = t_end
            self._check_wdt()
        if self.now >= self.stim.duration_us:
            self.finished = True

    def _pio_edge(self, t):
        sm = self.rp2040.sm.get(self.steer_pin)
        if sm is not None:
            sm.edge(t, 0 if self.steer_high else 1)

    def _edge(self, pin_no, level):
        if self.esp32 is not None:
            self.esp32.pin_edge(pin_no, level)  # the counters see the level it had until now
        self.pin_level[pin_no] = level
        h = self.irq.get(pin_no)
        if h is not None:
            handler, trig, pin, hard = h
            if (level and trig & 1) or (not level and trig & 2):
                if hard:  # in the interrupt, the heap locked
                    e = self._hard_irq(handler, pin)
                    if e is not None:
                        import sys
                        sys.print_exception(e)
                elif not self._schedule(pin_no):
                    self.sched_lost_pin += 1

    def idle(self):
        # Wait for the next interrupt, as machine.idle() does on the car.
        t = self.timer_due
        ts = self.t_steer
        if ts < t:
            t = ts
        th = self.t_hall
        if th < t:
            t = th
        if self.t_hall_rise < t:
            t = self.t_hall_rise
        if self.sched_n:
            t = self.now  # a queued callback is pending: the VM runs it at once
        if t >= _FAR:
            t = self.now + 1000
        end = self.stim.duration_us
        if t >= end:  # the stimulus covers [0, end): nothing happens at or after it
            self.now = end
            self.finished = True
            return
        self.advance_to(t)
        self.run_scheduled()

    # -- analog ---------------------------------------------------------------
    def volts_fine(self, pin_no):
        # the voltage at this instant [1e-6 of 0.1 mV], interpolated between the stimulus rows
        # (a held row would make a sample read between rows up to one row period, 200 us,
        # old). Not rounded here: the converter rounds once; flooring to whole 0.1 mV first
        # leaves an error that follows the sign of the slope, i.e. a timing error
        s = self.stim
        a = self.now * s.fs
        row = a // 1000000
        col = s.cols[pin_no]
        if row >= s.n_rows - 1:
            return s.volt(s.n_rows - 1, col) * 1000000
        w = s.volts
        i = w.cover(row, row + 1) * s.n_cols + col
        v0 = w.buf[i]
        v1 = w.buf[i + s.n_cols]
        return v0 * 1000000 + (v1 - v0) * (a % 1000000)

    def _adc_fault(self):
        if self.now >= self.adc_fault_at:  # a one-off read error (loose connector, EMI)
            self.adc_fault_at = _FAR
            raise OSError(5)

    def read_u16(self, pin_no):
        if self.rp2040 is not None and self.rp2040.adc.running:
            raise rp2040_hw.HwError("ADC.read_u16 while the ADC free-runs (START_MANY): it would select "
                                    "another input and break the round robin")
        self._adc_fault()
        v = self.volts_fine(pin_no)
        c = (v * 4095 + 16500000000) // 33000000000  # RP2040: 12 bits over 0..3.3 V, rounded once
        if c > 4095:
            c = 4095
        return (c << 4) | (c >> 8)  # as rp2's read_u16 scales 12 bits to 16

    def read_uv(self, pin_no):
        self._adc_fault()
        v = (self.volts_fine(pin_no) + 5000) // 10000  # uV; ESP32, 11 dB: linear 0.15..2.45 V only
        if v < 150000:
            v = 150000
        if v > 2450000:
            v = 2450000
        return v

    # -- output: throughput and stalls -----------------------------------------
    def stall_if_due(self, n):
        # A host that stops reading. A UART has no flow control: the write goes on and
        # the USB bridge drops what the host does not read (returns -1: all dropped).
        # USB-CDC: the write puts what fits in the TX FIFO and waits up to 500 ms for
        # room (interrupts keep firing); returns the bytes it took if it gives up
        # first, or n if the host reads again in time.
        while self.stall_i < len(self.stalls) and self.now >= self.stalls[self.stall_i][0]:
            at, d = self.stalls[self.stall_i]
            if self.now >= at + d:  # over: the host has read the FIFO empty
                self.stall_i += 1
                self.usb_fifo_free = self.tx_buf
                continue
            if self.baud is not None:
                return -1
            took = n if n < self.usb_fifo_free else self.usb_fifo_free
            self.usb_fifo_free -= took
            if took == n:
                return n
            if at + d <= self.now + _USB_TX_TIMEOUT_US:
                self.advance_to(at + d)
                self.stall_i += 1
                self.usb_fifo_free = self.tx_buf
                return n
            self.advance_to(self.now + _USB_TX_TIMEOUT_US)
            return took
        return n

    def transmit(self, n):
        # n bytes join the TX queue; the write returns when all but tx_buf bytes are
        # on the line (the driver blocks in C: hard IRQs fire, soft ones only queue).
        now_ns = self.now * 1000
        start = self.tx_idle_ns if self.tx_idle_ns > now_ns else now_ns
        self.tx_idle_ns = start + n * self.byte_ns
        self.tx_bytes += n
        done_us = (self.tx_idle_ns - self.tx_buf * self.byte_ns + 999) // 1000
        if done_us > self.now:
            self.advance_to(done_us)


class Output:
    def __init__(self, board, stream):
        self.board = board
        self._w = stream.write

    def write(self, buf, n=-1):
        b = self.board
        if n < 0:
            n = len(buf)
        if b.resetting:
            return n
        took = b.stall_if_due(n)
        if took < 0:  # a UART: the bridge dropped them
            b.transmit(n)
            b.run_scheduled()
            return n
        b.transmit(took)
        r = self._w(buf, took) if took else 0
        b.run_scheduled()  # back in the VM: queued callbacks run
        return r


BOARD = None


def board():
    global BOARD
    if BOARD is None:
        path = os.getenv("STID_SIM_STIMULUS")
        if not path:
            raise OSError("STID_SIM_STIMULUS is not set: the simulated board needs a stimulus file")
        BOARD = Board(path, realtime=os.getenv("STID_SIM_REALTIME") == "1")
        # Free the import-time garbage now, so the firmware's own allocations start from a
        # clean heap (MicroPython's allocator is first-fit from the lowest free block: when the
        # board still held its whole stimulus, small holes below those arrays made every call
        # that puts its frame on the heap scan past them, 13-17 s instead of 3.7 s for 4 min).
        import gc
        gc.collect()
    return BOARD
