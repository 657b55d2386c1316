# Boot entry on the car. `stid flash` writes config.py beside it.
try:
    import config
    _kw = {"board": config.BOARD, "rate_hz": config.RATE_HZ, "batch": config.BATCH}
    if getattr(config, "WHEELS", None) is not None:  # 4, or {position: pin}
        _kw["wheels"] = config.WHEELS
except ImportError:
    _kw = {}

import app

app.main(**_kw)
