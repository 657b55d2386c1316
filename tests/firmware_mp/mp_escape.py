# The escape `stid flash` uses: the app stops when ESCAPE arrives on its input,
# whatever bytes come around it, and not on a near miss. main.py's safe-boot check
# sees the flag file (and removes it) or the safe pin.
# usage: micropython mp_escape.py   (hil_sim/board first on MICROPYPATH)
import io
import os

import app
import boards
import simboard
from mptest import check, done

b = simboard.board()


class Sink:
    def write(self, buf, n=-1):
        return len(buf) if n < 0 else n


class OncePoll:
    # select.poll stand-in over a BytesIO: ready while bytes remain
    def __init__(self, stream, size):
        self.s = stream
        self.size = size

    def ipoll(self, timeout):
        if self.s.tell() < self.size:
            yield (self.s, 1)


def escaped_by(data):
    fw = app.App(board=b.stim.board, rate_hz=500, batch=10, out=Sink(), watchdog=False)
    fw.start()
    ctl = io.BytesIO(data)
    fw._control = ctl
    fw._poll = OncePoll(ctl, len(data))
    fw.check_escape()
    fw.stop()
    return fw.escaped


check(escaped_by(app.ESCAPE), "ESCAPE alone")
check(escaped_by(b"\x03\x03garbage STID-" + app.ESCAPE + b"\r\n"), "ESCAPE after noise and a partial match")
check(not escaped_by(app.ESCAPE[:-1] + b"X"), "a near miss does not escape")
check(not escaped_by(b"\x03" * 50), "Ctrl-C bytes do not escape (they are data)")

prof = boards.PROFILES[b.stim.board]
check(app.safe_boot_requested(prof) is None, "no flag, safe pin pulled up: the app starts")
with open(app.SAFE_BOOT_FILE, "w") as f:
    f.write("1")
check(app.safe_boot_requested(prof) == "escape", "the flag file asks for a safe boot")
try:
    os.stat(app.SAFE_BOOT_FILE)
    removed = False
except OSError:
    removed = True
check(removed, "the flag is removed (the next reset starts the app)")
b.pin_level[prof["safe_pin"]] = 0
check(app.safe_boot_requested(prof) == "pin", "safe pin held low")
done()
