# Run the car firmware on the simulated board until the stimulus ends.
# usage: micropython run_firmware.py RATE_HZ BATCH RING_SIZE
import sys

import app
import machine
import simboard

rate, batch, ring = (int(a) for a in sys.argv[1:4])
b = simboard.board()
h = b.stim.h
fw = app.App(board=b.stim.board, rate_hz=rate, batch=batch, ring_size=ring,
             out=simboard.Output(b, sys.stdout.buffer), extra_hello={"sim": True},
             wheels=h.get("wheels"), wheel_ppr=h.get("wheel_ppr"))
fw.run(should_stop=machine.sim_finished)
