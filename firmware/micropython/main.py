# Boot entry on the car. `stid flash` writes config.py beside it.
try:
    import config
    _kw = {"board": config.BOARD, "rate_hz": config.RATE_HZ, "batch": config.BATCH}
except ImportError:
    _kw = {}

import app

app.main(**_kw)
