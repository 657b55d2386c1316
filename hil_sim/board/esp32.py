# `esp32` for the simulated board: PCNT backed by esp32_hw (what that models, and what
# not, is described there). Only on a simulated "esp32"; STID_SIM_BOARD
# '{"esp32_pcnt": false}' takes PCNT away, to exercise the firmware's fallback.
import esp32_hw
import simboard

_b = simboard.board()
if _b.stim.board != "esp32":
    raise ImportError("no module named 'esp32'")


def _pin_no(p):
    if p is None:
        return -1
    return p if isinstance(p, int) else p.id


if _b.opts.get("esp32_pcnt", True):
    class PCNT:
        # ports/esp32/esp32_pcnt.c: the constants are ESP-IDF's (driver/pcnt_types_legacy.h)
        IGNORE = esp32_hw.COUNT_DIS
        INCREMENT = esp32_hw.COUNT_INC
        DECREMENT = esp32_hw.COUNT_DEC
        NORMAL = esp32_hw.MODE_KEEP
        REVERSE = esp32_hw.MODE_REVERSE
        HOLD = esp32_hw.MODE_DISABLE
        IRQ_THRESHOLD1 = 1 << 2
        IRQ_THRESHOLD0 = 1 << 3
        IRQ_MIN = 1 << 4
        IRQ_MAX = 1 << 5
        IRQ_ZERO = 1 << 6

        def __init__(self, id, **kw):
            if not 0 <= id < esp32_hw.N_UNITS:
                raise ValueError("invalid id")
            self._id = id
            self.init(**kw)

        def _unit(self):
            return _b.esp32.units[self._id]  # (the chip of now: a reset makes a new one)

        def init(self, channel=0, pin=False, rising=None, falling=None, mode_pin=False, mode_low=None,
                 mode_high=None, min=None, max=None, filter=None, threshold0=None, threshold1=None,
                 value=None):
            # the argument rules of esp32_pcnt_init_helper; False: not given
            u = self._unit()
            if channel not in (0, 1):
                raise ValueError("channel")
            if channel == 1:
                if (pin not in (False, None)) or (rising not in (None, PCNT.IGNORE)):
                    raise esp32_hw.HwError("simulated PCNT: channel 1 is not modelled")
                return
            if pin is not False or mode_pin is not False:
                if pin is False:
                    raise ValueError("pin")
                u.set_pins(_pin_no(pin), -1 if mode_pin is False else _pin_no(mode_pin))
            if rising is not None or falling is not None or mode_low is not None or mode_high is not None:
                u.set_mode(PCNT.IGNORE if rising is None else rising, PCNT.IGNORE if falling is None else falling,
                           PCNT.NORMAL if mode_low is None else mode_low,
                           PCNT.NORMAL if mode_high is None else mode_high)
            if filter is not None and not 0 <= filter <= 1023:
                raise ValueError("filter")
            clear = False
            if value is not None:
                if value != 0:
                    raise ValueError("value")
                clear = True
            if min is not None:
                if not -32768 <= min <= 0:
                    raise ValueError("minimum")
                u.l_lim = min
                clear = True
            if max is not None:
                if not 0 <= max <= 32767:
                    raise ValueError("maximum")
                u.h_lim = max
                clear = True
            if threshold0 is not None or threshold1 is not None:
                clear = True
            if clear:
                u.clear()

        def value(self, v=None):
            if v is not None and v != 0:
                raise ValueError("value")
            u = self._unit()
            r = u.value()
            if v is not None:
                u.clear()
            return r

        def start(self):
            self._unit().start()

        def stop(self):
            self._unit().stop()

        def deinit(self):
            self._unit().deinit()

        def irq(self, handler=None, trigger=None):
            raise esp32_hw.HwError("simulated PCNT: irq is not modelled")
