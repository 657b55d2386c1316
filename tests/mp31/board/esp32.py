# `esp32` for the scripted board: the pulse counter (scripted_board.PcntUnit), with the
# argument rules of ports/esp32/esp32_pcnt.c (esp32_pcnt_init_helper) for what the
# firmware passes. Only on an "esp32" board with its PCNT on (Board(pcnt=False): the
# firmware's fallback to pin interrupts).
import scripted_board

_b = scripted_board.BOARD
if not _b.pcnt:
    raise ImportError("no module named 'esp32'")

_UNSET = object()


def _pin_no(p):
    return p if isinstance(p, int) else p.id


class PCNT:
    IGNORE = 0
    INCREMENT = 1
    DECREMENT = 2
    NORMAL = 0
    REVERSE = 1
    HOLD = 2

    def __init__(self, id, **kw):
        if not 0 <= id < 8:
            raise ValueError("invalid id")
        self._u = _b.units[id]
        self.init(**kw)

    def init(self, channel=0, pin=_UNSET, rising=_UNSET, falling=_UNSET, mode_pin=_UNSET, mode_low=_UNSET,
             mode_high=_UNSET, min=_UNSET, max=_UNSET, filter=_UNSET, value=_UNSET):
        u = self._u
        if channel != 0:
            raise ValueError("scripted board: only channel 0 is modelled")
        if pin is not _UNSET or mode_pin is not _UNSET:
            if pin is _UNSET:
                raise ValueError("pin")
            u.set_pins(-1 if pin is None else _pin_no(pin),
                       -1 if mode_pin is _UNSET or mode_pin is None else _pin_no(mode_pin))
        if rising is not _UNSET or falling is not _UNSET or mode_low is not _UNSET or mode_high is not _UNSET:
            u.rising = PCNT.IGNORE if rising is _UNSET else rising
            u.falling = PCNT.IGNORE if falling is _UNSET else falling
            u.mode_low = PCNT.NORMAL if mode_low is _UNSET else mode_low
            u.mode_high = PCNT.NORMAL if mode_high is _UNSET else mode_high
            for m in (u.rising, u.falling):
                if m not in (PCNT.IGNORE, PCNT.INCREMENT):
                    raise ValueError("scripted board: only INCREMENT and IGNORE are modelled")
            for m in (u.mode_low, u.mode_high):
                if m not in (PCNT.NORMAL, PCNT.HOLD):
                    raise ValueError("scripted board: only NORMAL and HOLD are modelled")
        if filter is not _UNSET:
            if not 0 <= filter <= 1023:
                raise ValueError("filter")
            u.filter_us = filter // 80  # APB cycles at 80 MHz
        clear = False
        if value is not _UNSET:
            if value != 0:
                raise ValueError("value")
            clear = True
        if min is not _UNSET:
            if not -32768 <= min <= 0:
                raise ValueError("minimum")
            clear = True
        if max is not _UNSET:
            if not 0 <= max <= 32767:
                raise ValueError("maximum")
            u.h_lim = max
            clear = True
        if clear:
            u.reg = 0

    def value(self, v=None):
        r = self._u.reg
        if v is not None:
            if v != 0:
                raise ValueError("value")
            self._u.reg = 0
        return r

    def start(self):
        self._u.running = True

    def stop(self):
        self._u.running = False

    def deinit(self):
        self._u.deinit()
