# `rp2` for the simulated board: DMA, asm_pio, StateMachine and PIO constants backed
# by rp2040_hw (what that models, and what not, is described there). Only on a
# simulated "pico"; STID_SIM_BOARD '{"rp2_dma": false}' takes DMA away (MicroPython
# before 1.22) and '{"rp2_pio": false}' the PIO, to exercise the firmware's fallbacks.
import simboard

_b = simboard.board()
if _b.stim.board != "pico":
    raise ImportError("no module named 'rp2'")


class PIO:
    SHIFT_LEFT = 0
    SHIFT_RIGHT = 1
    JOIN_NONE = 0
    JOIN_TX = 1
    JOIN_RX = 2
    IN_LOW = 0
    IN_HIGH = 1
    OUT_LOW = 2
    OUT_HIGH = 3
    IRQ_SM0 = 0x100


def asm_pio(**kw):
    import rp2040_hw

    def dec(f):
        return rp2040_hw.PioProgram(f, kw)

    return dec


if _b.opts.get("rp2_pio", True):
    def StateMachine(sm_id, prog=None, freq=None, **kw):  # noqa: N802  (a class on the chip)
        return _b.rp2040.make_sm(sm_id, prog, freq, **kw)  # (the chip of now: a reset makes a new one)

if _b.opts.get("rp2_dma", True):
    def DMA():  # noqa: N802
        return _b.rp2040.claim_dma()
