# The hot path allocates nothing: the sampler interrupt, building and sending
# sample frames, STATUS and HELLO all run under micropython.heap_lock(), on the
# simulated board (run with hil_sim/board first on MICROPYPATH).

import micropython

import app
import simboard
from mptest import check, done, run_heap_locked


class Sink:
    # stands in for the serial port; keeps byte counts only (no allocation)
    def __init__(self):
        self.n = 0

    def write(self, buf, n=-1):
        self.n += len(buf) if n < 0 else n
        return len(buf) if n < 0 else n


b = simboard.board()
sink = Sink()
fw = app.App(board=b.stim.board, rate_hz=1000, batch=10, ring_size=64, out=sink, wheels=b.stim.h.get("wheels"))
fw.start()


def drive(steps):
    return run_heap_locked(b, fw, steps)


check(drive(2000), "sampler + pump + service allocate nothing (heap locked)")
samples = fw.sampler.index
check(samples > 1500, "sampler ran (%d samples)" % samples)
check(fw.steer.width > 0, "servo pulses captured")
check(fw.wheel.count > 0, "hall pulses counted")
check(fw.steer.t_fall > 0, "servo falling edges timed")
if len(fw.wheels) == 4:
    check(min(w.count for w in fw.wheels) > 0, "four hall sensors counted")


def hello_status():
    micropython.heap_lock()
    try:
        fw.send_hello()
        fw.send_status()
        result = True
    except MemoryError:
        result = False
    micropython.heap_unlock()
    return result


check(hello_status(), "HELLO and STATUS allocate nothing")
check(sink.n > 0, "bytes written")
done()
