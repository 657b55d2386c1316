# The escape through the real input path: select.poll on this process's stdin (a
# pipe the test writes STID-ESCAPE into), checked by the main loop under
# micropython.heap_lock(): finding it allocates nothing.
# usage: printf 'xxSTID-ESCAPE' | micropython mp_escape_live.py   (hil_sim/board first on MICROPYPATH)
import sys


import app
import simboard
from mptest import check, done, run_heap_locked

b = simboard.board()


class Sink:
    def write(self, buf, n=-1):
        return len(buf) if n < 0 else n


fw = app.App(board=b.stim.board, rate_hz=500, batch=10, out=Sink(), control=sys.stdin.buffer)
fw.start()
check(fw._poll is not None, "stdin is polled")


def drive(steps):
    return run_heap_locked(b, fw, steps)


check(drive(2000), "main loop with the escape check allocates nothing (heap locked)")
check(fw.escaped, "STID-ESCAPE on stdin stops the app")
check(fw.sampler.index < 600, "within ~1 s of virtual time (%d samples)" % fw.sampler.index)
fw.stop()
done()
