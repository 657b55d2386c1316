# Boot entry on the car. `stid flash` writes config.py beside it.
#
# Ways back to the REPL (the app disables Ctrl-C so that a 0x03 data byte cannot
# stop it; mpremote needs Ctrl-C): (1) `stid flash` sends app.ESCAPE, the app
# reboots with a flag file and this script stops before the app; (2) the board's
# safe pin held low at reset (Pico GP22 to GND; ESP32 the BOOT button, pressed
# just after reset); (3) Ctrl-C within BOOT_WINDOW_MS of reset, from any terminal.
import time

BOOT_WINDOW_MS = 1000

try:
    import config
    _kw = {"board": config.BOARD, "rate_hz": config.RATE_HZ, "batch": config.BATCH}
    if getattr(config, "WHEELS", None) is not None:  # 4, or {position: pin}
        _kw["wheels"] = config.WHEELS
except ImportError:
    _kw = {}

import app
import boards

_board = _kw.get("board") or app.default_board()
_why = app.safe_boot_requested(boards.PROFILES[_board])
if _why:
    print("stid: safe boot (%s): the app is not started; the REPL is yours" % _why)
else:
    time.sleep_ms(BOOT_WINDOW_MS)  # Ctrl-C still works here
    app.main(**_kw)
