# Run the car firmware on the simulated board until the stimulus ends.
# usage: micropython run_firmware.py RATE_HZ BATCH RING_SIZE   (RING_SIZE 0: the default)
# A watchdog reset boots the firmware again on the same clock, as the chip would.
import sys

import app
import machine
import simboard

rate, batch, ring = (int(a) for a in sys.argv[1:4])
b = simboard.board()
h = b.stim.h
kw = {"ring_size": ring} if ring else {}
try:
    while True:
        fw = app.App(board=b.stim.board, rate_hz=rate, batch=batch,
                     out=simboard.Output(b, sys.stdout.buffer), extra_hello={"sim": True},
                     wheels=h.get("wheels"), wheel_ppr=h.get("wheel_ppr"), **kw)
        try:
            fw.run(should_stop=machine.sim_finished)
            break
        except simboard.WatchdogReset:
            sys.stderr.write("simboard: watchdog reset at %d us\n" % b.now)
            b.reboot("watchdog")
except Exception as e:  # noqa: BLE001 - the unix port prints an uncaught one on stdout, among the
    sys.print_exception(e, sys.stderr)  # firmware's bytes, where the host would take it for data
    sys.exit(1)
