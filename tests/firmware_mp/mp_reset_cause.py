# reset_cause on the simulated board: rp2 reads WDT_RESET after machine.reset() as well
# as after a watchdog timeout; the firmware tells them apart by watchdog scratch 4 (the
# pico-sdk writes its magic there in watchdog_enable, 0 in watchdog_reboot). And
# micropython.kbd_intr is given back to Ctrl-C on every way out of app.main().
# usage: micropython mp_reset_cause.py   (hil_sim/board first on MICROPYPATH, a pico stimulus)
import app
import boards
import machine
import simboard
from mptest import check, done

b = simboard.board()
check(b.stim.board == "pico", "a Pico stimulus")
check(boards.reset_cause("pico") == "power_on", "power on")
machine.WDT(timeout=2000)
b.reboot("watchdog")  # not fed: the watchdog resets the chip
check(machine.reset_cause() == machine.WDT_RESET, "rp2 reads WDT_RESET after a watchdog timeout")
check(boards.reset_cause("pico") == "watchdog", "a watchdog timeout reads watchdog")
try:
    machine.reset()
    reset = False
except simboard.MachineReset:
    reset = True
check(reset and machine.reset_cause() == machine.WDT_RESET, "rp2 reads WDT_RESET after machine.reset() too")
check(boards.reset_cause("pico") == "soft", "machine.reset() (an escape, a flash) reads soft, not watchdog")
machine.WDT(timeout=2000)
b.reboot("watchdog")
check(boards.reset_cause("pico") == "watchdog", "the next watchdog timeout reads watchdog again")


class KbdIntr:
    # stands in for the micropython module inside app: records kbd_intr calls
    def __init__(self):
        self.calls = []

    def kbd_intr(self, c):
        self.calls.append(c)


def main_raises(**kw):
    real = app.micropython
    app.micropython = KbdIntr()
    try:
        app.main(board="pico", **kw)
        raised = False
    except ValueError:
        raised = True
    calls = app.micropython.calls
    app.micropython = real
    return raised, calls


raised, calls = main_raises(rate_hz=7)  # App() refuses the rate
check(raised and calls == [-1, 3], "App() raising: Ctrl-C given back (%r)" % calls)
done()
