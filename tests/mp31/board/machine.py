# `machine` for the scripted board (scripted_board.py): what the firmware uses of it.
import scripted_board


def _b():
    return scripted_board.BOARD


class Pin:
    IN = 0
    OUT = 1
    PULL_UP = 1
    PULL_DOWN = 2
    IRQ_RISING = 1
    IRQ_FALLING = 2

    def __init__(self, id, mode=-1, pull=-1):
        self.id = id
        b = _b()
        if id not in b.level:
            b.level[id] = 1 if pull == Pin.PULL_UP else 0

    def value(self, v=None):
        return _b().level[self.id]

    def irq(self, handler=None, trigger=3, **kw):
        b = _b()
        if "hard" in kw and b.name == "esp32":
            raise TypeError("unexpected keyword argument 'hard'")  # ports/esp32/machine_pin.c
        b.irq[self.id] = [handler, trigger, self, bool(kw.get("hard"))]


class ADC:
    ATTN_0DB = 0
    ATTN_11DB = 3

    def __init__(self, pin, atten=None):
        self._pin = pin.id
        b = _b()
        b.adc_u16.setdefault(pin.id, 0)
        b.adc_uv.setdefault(pin.id, 150000)

    def read_u16(self):
        return _b().adc_u16[self._pin]

    def read_uv(self):
        return _b().adc_uv[self._pin]


class Timer:
    PERIODIC = 1
    ONE_SHOT = 0

    def __init__(self, id=-1):
        pass

    def init(self, mode=1, freq=None, period=None, callback=None, hard=None):
        b = _b()
        if hard and b.name == "esp32":
            raise ValueError("hard Timers are not implemented")  # ports/esp32/machine_timer.c
        b.timer_period = 1000000 // freq
        b.timer_cb = callback
        b.timer_hard = bool(hard)
        b.timer_due = b.abs_us + b.timer_period

    def deinit(self):
        _b().timer_due = -1


class PWM:
    # a 1 MHz clock (servo_pcnt.py's): scripted_board.PcntUnit counts it
    def __init__(self, pin, freq=None, duty_u16=None, **kw):
        if freq != 1000000:
            raise ValueError("scripted board: only a 1 MHz PWM is modelled")
        self._pin = pin.id
        _b().clock_pins[self._pin] = True  # driving, its input on (machine_pwm.c reconfigure_pin)

    def deinit(self):
        _b().clock_pins.pop(self._pin, None)


class UART:
    def __init__(self, id, baudrate=None, **kw):
        pass


class WDT:
    def __init__(self, id=0, timeout=5000):
        b = _b()
        b.wdt_timeout_ms = timeout
        b.wdt_fed_ms = b.ticks_ms
        if b.name == "pico":
            b.wdt_scratch4 = 0x6AB73121  # pico-sdk watchdog_enable

    def feed(self):
        b = _b()
        b.wdt_fed_ms = b.ticks_ms


_ADC_CS = 0x4004C000
_ADC_FCS = 0x4004C008
_ADC_DIV = 0x4004C010
_WDT_SCRATCH4 = 0x4005801C


class _Mem32:
    def __getitem__(self, addr):
        b = _b()
        if addr == _ADC_CS:
            return 0x100  # READY
        if addr == _ADC_FCS:
            return 0  # FIFO empty
        if addr == _WDT_SCRATCH4:
            return b.wdt_scratch4
        raise OSError("scripted board: no register at 0x%x" % addr)

    def __setitem__(self, addr, v):
        b = _b()
        if addr == _ADC_CS:
            if v & 8 and b.scan_t0_abs < 0:  # START_MANY: the round robin starts now
                b.scan_t0_abs = b.abs_us
            elif not v & 8:
                b.scan_t0_abs = -1
        elif addr == _ADC_DIV:
            b.scan_us = ((v >> 8) + 1) // 12  # 4 conversions of (DIV + 1) cycles at 48 MHz
        elif addr == _WDT_SCRATCH4:
            b.wdt_scratch4 = v
        elif addr != _ADC_FCS:
            raise OSError("scripted board: no register at 0x%x" % addr)


mem32 = _Mem32()

PWRON_RESET = 1
HARD_RESET = 2
WDT_RESET = 3
DEEPSLEEP_RESET = 4
SOFT_RESET = 5


def reset_cause():
    return _b().reset_cause


def unique_id():
    return b"\x01\x02\x03\x04\x05\x06\x07\x08" if _b().name == "pico" else b"\x01\x02\x03\x04\x05\x06"


def idle():
    pass
