# `rp2` for the scripted board: a DMA that only holds its configuration (the ring's
# contents are written by scripted_board.dma_fill) and a state machine whose RX FIFO
# receives what servo_pio.py's program pushes (scripted_board.pio_pulse).
import scripted_board

_b = scripted_board.BOARD
if _b.name != "pico":
    raise ImportError("no module named 'rp2'")


class PIO:
    SHIFT_LEFT = 0
    SHIFT_RIGHT = 1
    JOIN_NONE = 0
    JOIN_TX = 1
    JOIN_RX = 2


def asm_pio(**kw):
    def dec(f):
        return f  # the program itself is run in tests/test_board_capture.py

    return dec


if _b.pio:
    def StateMachine(sm_id, prog=None, freq=None, jmp_pin=None, **kw):  # noqa: N802
        sm = scripted_board.StateMachine(_b)
        _b.sm = sm
        return sm


class _Dma:
    def __init__(self, n):
        import uctypes

        self.channel = n
        self.registers = bytearray(64)
        self.base = 0
        self.write = 0
        self._addressof = uctypes.addressof

    def active(self, v=None):
        return 0

    def pack_ctrl(self, **kw):
        return 0

    def config(self, read=None, write=None, count=None, ctrl=None, trigger=False):
        if not isinstance(write, int):
            self.base = self._addressof(write)
            self.write = self.base


if _b.dma:
    def DMA():  # noqa: N802
        d = _Dma(len(_b.dmas))
        _b.dmas.append(d)
        return d
