# The ESP32 peripherals the firmware programs directly, for the simulated board: the
# LEDC PWM (machine.PWM) as a clock and the pulse counter units (esp32.PCNT).
#
# What they do, from the sources (micropython ports/esp32/esp32_pcnt.c and
# machine_pwm.c; ESP-IDF components/driver/deprecated/pcnt_legacy.c):
# - A PCNT unit's channel counts edges of its `pin` (rising / falling: INCREMENT,
#   DECREMENT or IGNORE); while its `mode_pin` is low the action is changed by
#   mode_low, while high by mode_high: NORMAL keeps it, HOLD stops counting, REVERSE
#   inverts it. The count is a signed 16-bit register that returns to 0 when it
#   reaches `max` (h_lim) or `min` (l_lim); `start`/`stop` resume/pause it.
# - `_pcnt_set_pin` makes both pins inputs (gpio_set_direction(..., GPIO_MODE_INPUT)):
#   a PWM already on the pulse pin stops driving it (its count stays 0). A PWM set up
#   after the PCNT drives the pad and keeps its input on (machine_pwm.c
#   reconfigure_pin: "This allows to read the pin level"), so the unit counts it.
# - The PWM's clock: LEDC divides the 80 MHz APB (same crystal as ticks_us): at 1 MHz
#   its rising edges are 1 us apart to one APB cycle, from an arbitrary phase.
#
# The stimulus's edges are whole microseconds; a chip's are not, so each servo edge is
# given a sub-microsecond phase here (a fixed sequence): the count of a 1 MHz clock
# over a pulse is then its width rounded either way, as on the chip.
#
# Nothing here allocates while events fire (the firmware's allocation test).

COUNT_DIS = 0  # PCNT_COUNT_DIS / INC / DEC (driver/pcnt_types_legacy.h)
COUNT_INC = 1
COUNT_DEC = 2
MODE_KEEP = 0  # PCNT_MODE_KEEP / REVERSE / DISABLE
MODE_REVERSE = 1
MODE_DISABLE = 2
N_UNITS = 8  # ESP32: 8 units (SOC_PCNT_UNITS_PER_GROUP)
_NONE = -1


class HwError(Exception):
    """The firmware asked the simulated peripheral for something it does not model."""


class PcntUnit:
    def __init__(self, hw, unit):
        self.hw = hw
        self.unit = unit
        self.deinit()

    def deinit(self):
        self.pulse_pin = _NONE
        self.ctrl_pin = _NONE
        self.rising = COUNT_DIS
        self.falling = COUNT_DIS
        self.mode_low = MODE_KEEP
        self.mode_high = MODE_KEEP
        self.h_lim = 0
        self.l_lim = 0
        self.reg = 0
        self.running = False
        self.seg_ns = 0  # clock edges are counted from here (the last ctrl change)

    # -- configuration (PCNT.init) ------------------------------------------------
    def set_pins(self, pulse, ctrl):
        self.flush()
        self.pulse_pin = pulse
        self.ctrl_pin = ctrl
        self.hw.claim_input(pulse)

    def set_mode(self, rising, falling, mode_low, mode_high):
        self.flush()
        if rising == COUNT_DEC or falling == COUNT_DEC or mode_low == MODE_REVERSE or mode_high == MODE_REVERSE:
            raise HwError("simulated PCNT: only counting up is modelled (INCREMENT, NORMAL, HOLD)")
        self.rising = rising
        self.falling = falling
        self.mode_low = mode_low
        self.mode_high = mode_high

    def clear(self):
        self.flush()
        self.reg = 0

    def start(self):
        self.flush()
        self.running = True

    def stop(self):
        self.flush()
        self.running = False

    # -- counting -------------------------------------------------------------------
    def _gain(self, ctrl_level):
        mode = self.mode_high if ctrl_level else self.mode_low
        return 0 if mode == MODE_DISABLE else 1

    def _add(self, n):
        if n <= 0:
            return
        r = self.reg + n
        if self.h_lim > 0:
            r %= self.h_lim  # the register returns to 0 each time it reaches max
        else:
            r = ((r + 32768) & 0xFFFF) - 32768
        self.reg = r

    def flush(self):
        # count the clock edges since seg_ns under the control level that held there
        now_ns = self.hw.now_ns()
        if now_ns <= self.seg_ns:  # an edge's sub-us phase put seg_ns ahead of the clock
            return
        if self.running and self.ctrl_pin != self.pulse_pin:
            clk = self.hw.clock_on(self.pulse_pin)
            if clk is not None and self._gain(self.hw.level(self.ctrl_pin)):
                n = 0
                if self.rising == COUNT_INC:
                    n += clk.edges(self.seg_ns, now_ns, 0)
                if self.falling == COUNT_INC:
                    n += clk.edges(self.seg_ns, now_ns, clk.period_ns // 2)
                self._add(n)
        self.seg_ns = now_ns

    def pin_edge(self, pin, level, t_ns):
        # an edge of a stimulus pin at t_ns (before the board's level changes)
        if pin == self.ctrl_pin:
            self.hw.at_ns = t_ns
            self.flush()
            self.hw.at_ns = -1
        if pin == self.pulse_pin and self.running:
            act = self.rising if level else self.falling
            if act == COUNT_INC and self._gain(self.hw.level(self.ctrl_pin)):
                self._add(1)

    def value(self):
        self.flush()
        return self.reg


class Clock:
    """A PWM output: rising edges at t0_ns + k * period_ns, 50% duty."""

    def __init__(self):
        self.pin = _NONE
        self.t0_ns = 0
        self.period_ns = 0
        self.driving = False

    def edges(self, a_ns, b_ns, offset_ns):
        # edges (at t0 + offset + k * period, k >= 0) in [a_ns, b_ns)
        t0 = self.t0_ns + offset_ns
        p = self.period_ns
        na = (a_ns - t0 + p - 1) // p
        nb = (b_ns - t0 + p - 1) // p
        if na < 0:
            na = 0
        if nb < 0:
            nb = 0
        return nb - na


class Esp32:
    def __init__(self, board):
        self.board = board
        self.units = [PcntUnit(self, u) for u in range(N_UNITS)]
        self.clocks = [Clock() for _ in range(4)]
        self.at_ns = -1  # while an edge is handled: its instant with the sub-us phase
        # STID_SIM_BOARD '{"esp32_pwm_readback": false}': a PWM pad whose input is off, so
        # a PCNT on it counts nothing (the firmware's self-test must notice)
        self.readback = board.opts.get("esp32_pwm_readback", True)
        self.n_edges = 0

    def now_ns(self):
        return self.at_ns if self.at_ns >= 0 else self.board.now * 1000

    def level(self, pin):
        if pin == _NONE:
            return 1  # an unconnected control input reads high (NORMAL counting either way here)
        clk = self.clock_on(pin)
        if clk is not None:
            raise HwError("simulated PCNT: a PWM as control input is not modelled")
        return self.board.pin_level.get(pin, 0)

    def clock_on(self, pin):
        if not self.readback:
            return None
        for c in self.clocks:
            if c.pin == pin and c.driving:
                return c
        return None

    def claim_input(self, pin):
        # pcnt_set_pin: GPIO_MODE_INPUT, the output driver is off
        for c in self.clocks:
            if c.pin == pin:
                c.driving = False

    def pwm_start(self, pin, freq):
        if not 1 <= freq <= 40000000:
            raise ValueError("frequency must be from 1Hz to 40MHz")
        if 1000000000 % freq:
            raise HwError("simulated PWM: a period of whole ns is modelled (1 MHz, ...)")
        for u in self.units:
            u.flush()
        c = None
        for k in self.clocks:
            if k.pin == pin or (c is None and k.pin == _NONE):
                c = k
        if c is None:
            raise HwError("simulated PWM: at most 4 outputs")
        c.pin = pin
        c.period_ns = 1000000000 // freq
        c.t0_ns = self.board.now * 1000 + 371  # an arbitrary phase, off the stimulus's us grid
        c.driving = True

    def pwm_stop(self, pin):
        for u in self.units:
            u.flush()
        for c in self.clocks:
            if c.pin == pin:
                c.pin = _NONE
                c.driving = False

    def pin_edge(self, pin, level):
        # called by the board just before a stimulus pin changes level
        self.n_edges += 1
        t_ns = self.board.now * 1000 + (self.n_edges * 389) % 1000 - 500
        for u in self.units:
            if u.pulse_pin == pin or u.ctrl_pin == pin:
                u.pin_edge(pin, level, t_ns)
