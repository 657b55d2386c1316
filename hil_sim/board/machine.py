# `machine` for the simulated board: Pin, ADC and Timer backed by simboard.
from umachine import *  # noqa: F401,F403  (whatever the unix port has)

import simboard

_b = simboard.board()


class Pin:
    IN = 0
    OUT = 1
    PULL_UP = 1
    PULL_DOWN = 2
    IRQ_RISING = 1
    IRQ_FALLING = 2

    def __init__(self, id, mode=-1, pull=-1):
        self.id = id
        self._idle = 1 if pull == Pin.PULL_UP else 0  # an unconnected pin reads its pull

    def value(self, v=None):
        return _b.pin_level.get(self.id, self._idle)

    def irq(self, handler=None, trigger=3, **kw):
        # rp2: hard=True runs the handler in the interrupt (simboard: with the heap locked),
        # else it is scheduled. ESP32: Pin.irq takes handler, trigger and wake only
        # (ports/esp32/machine_pin.c); every pin callback is scheduled (simboard: the queue
        # it shares with the timer).
        hard = kw.pop("hard", None)
        kw.pop("wake", None)
        if kw or (hard is not None and _b.stim.board == "esp32"):
            raise TypeError("unexpected keyword argument")
        if handler is None:
            _b.irq.pop(self.id, None)
        else:
            _b.irq[self.id] = (handler, trigger, self, bool(hard))


class PWM:
    # ESP32 only (esp32_hw.Esp32: the LEDC output as a clock for the pulse counters);
    # the default duty is 50% (machine_pwm.c PWM_DUTY), the only one modelled
    def __init__(self, dest, freq=None, duty_u16=None, **kw):
        if _b.esp32 is None:
            raise OSError("simulated board: PWM is only modelled on the esp32")
        self._pin = dest if isinstance(dest, int) else dest.id
        self.init(freq=freq, duty_u16=duty_u16, **kw)

    def init(self, freq=None, duty_u16=None, **kw):
        if kw or duty_u16 not in (None, 32768):
            raise OSError("simulated PWM: only freq and a 50% duty are modelled")
        self._freq = 5000 if freq is None else freq  # machine_pwm.c PWM_FREQ
        _b.esp32.pwm_start(self._pin, self._freq)

    def freq(self, f=None):
        if f is None:
            return self._freq
        self.init(freq=f)

    def deinit(self):
        _b.esp32.pwm_stop(self._pin)


class ADC:
    ATTN_0DB = 0
    ATTN_11DB = 3

    def __init__(self, pin, atten=None):
        if not isinstance(pin, Pin):
            raise ValueError("use ADC(Pin(n)): by channel number the pad pull-down stays on (rp2)")
        if pin.id not in _b.stim.cols:
            raise ValueError("no analog signal on pin %d in this simulation" % pin.id)
        self._pin = pin.id

    def read_u16(self):
        return _b.read_u16(self._pin)

    def read_uv(self):
        return _b.read_uv(self._pin)


class Timer:
    PERIODIC = 1
    ONE_SHOT = 0

    def __init__(self, id=-1, **kw):
        if kw:
            self.init(**kw)

    def init(self, mode=1, freq=None, period=None, callback=None, **kw):
        # As the ports do: ESP32 refuses hard=True (ValueError, "hard Timers are not
        # implemented"); rp2 before 1.26 has no `hard` keyword (TypeError).
        hard = kw.pop("hard", None)
        if kw:
            raise TypeError("unexpected keyword argument")
        if hard is not None and _b.stim.board == "pico" and _b.micropython < (1, 26, 0):
            raise TypeError("unexpected keyword argument 'hard'")
        if hard and _b.stim.board == "esp32":
            raise ValueError("hard Timers are not implemented")
        period_us = 1000000 // freq if freq else period * 1000
        _b.timer_period = period_us
        _b.timer_cb = callback
        _b.timer_obj = self
        _b.timer_soft = not hard
        _b.timer_due = _b.now + period_us

    def deinit(self):
        _b.timer_due = simboard._FAR
        _b.timer_cb = None


_WDT_SCRATCH4 = 0x4005801C


class _Mem32:
    # machine.mem32: only the RP2040 ADC registers (rp2040_hw.Adc) and watchdog scratch
    # register 4 exist here
    def _adc(self, addr):
        hw = _b.rp2040
        if hw is None or not 0x4004C000 <= addr < 0x4004C024:
            raise OSError("simulated board: no register at 0x%x" % addr)
        return hw.adc

    def __getitem__(self, addr):
        if addr == _WDT_SCRATCH4 and _b.rp2040 is not None:
            return _b.wdt_scratch4
        return self._adc(addr).read(addr)

    def __setitem__(self, addr, v):
        if addr == _WDT_SCRATCH4 and _b.rp2040 is not None:
            _b.wdt_scratch4 = v
            return
        self._adc(addr).write(addr, v)


mem32 = _Mem32()


class UART:
    # Only what the firmware uses: the console UART's baud rate (ESP32 UART 0).
    def __init__(self, id, baudrate=None, **kw):
        self.id = id
        self.init(baudrate=baudrate, **kw)

    def init(self, baudrate=None, **kw):
        if baudrate and self.id == 0 and _b.stim.board == "esp32":
            _b.set_baud(baudrate)


class WDT:
    def __init__(self, id=0, timeout=5000):
        if _b.stim.board == "pico" and timeout > 8388:
            raise ValueError("timeout exceeds 8388")  # rp2: 24-bit counter
        _b.wdt_timeout = timeout * 1000
        _b.wdt_fed = _b.now
        if _b.stim.board == "pico":
            _b.wdt_scratch4 = simboard.WDT_NON_REBOOT_MAGIC  # pico-sdk watchdog_enable

    def feed(self):
        _b.wdt_fed = _b.now


PWRON_RESET = 1
HARD_RESET = 2
WDT_RESET = 3
DEEPSLEEP_RESET = 4
SOFT_RESET = 5


def reset_cause():
    return _b.reset_cause


def reset():
    # rp2: watchdog_reboot(0, ...) writes 0 to watchdog scratch 4 and resets through the
    # watchdog (reset_cause reads WDT_RESET); ESP32: esp_restart, SOFT_RESET
    if _b.stim.board == "pico":
        _b.wdt_scratch4 = 0
        _b.reboot("watchdog")
    else:
        _b.reboot("soft")
    raise simboard.MachineReset()


def unique_id():
    return _b.uid


def idle():
    _b.idle()


def sim_finished():
    return _b.finished
