# The simulated board reads its stimulus through small windows (hil_sim/board/stimfile.py):
# reloading one, while interrupts fire, allocates nothing, and every row read through a
# window is the file's. Run with STID_SIM_BOARD='{"stim_rows": 3}' so windows reload all the time.
# usage: micropython mp_stim_window.py   (hil_sim/board first on MICROPYPATH)
import os
import struct


import app
import simboard
from mptest import check, done, run_heap_locked

b = simboard.board()
s = b.stim
check(s.volts.cap == 3 and s.steer.cap == 3 and s.hall.cap == 3, "three-row windows")


class Sink:
    def write(self, buf, n=-1):
        return len(buf) if n < 0 else n


fw = app.App(board=s.board, rate_hz=1000, batch=10, ring_size=64, out=Sink(), wheels=s.h.get("wheels"))
fw.start()


def drive(steps):
    return run_heap_locked(b, fw, steps)


base0 = (s.volts.base, s.steer.base, s.hall.base)
check(drive(3000), "sampler, pulses and window reloads allocate nothing (heap locked)")
check(s.volts.base != base0[0] and s.steer.base != base0[1] and s.hall.base != base0[2],
      "every window moved on (%d, %d, %d)" % (s.volts.base, s.steer.base, s.hall.base))
check(fw.sampler.index > 2000, "sampler ran (%d samples)" % fw.sampler.index)

# every row, read through the window in any order, is the file's
f = open(os.getenv("STID_SIM_STIMULUS"), "rb")
f.seek(8)
(hlen,) = struct.unpack("<I", f.read(4))
f.seek(12 + hlen)
raw = f.read(2 * s.n_rows * s.n_cols)
bad = 0
for row in list(range(s.n_rows - 1, -1, -97)) + list(range(0, s.n_rows, 89)):
    for col in range(s.n_cols):
        if s.volt(row, col) != struct.unpack_from("<H", raw, 2 * (row * s.n_cols + col))[0]:
            bad += 1
check(bad == 0, "rows read backwards and forwards through the window are the file's (%d wrong)" % bad)
done()
