"""The simulated car's side: its accelerometer reads 6% low (written without stid)."""

NAME = "accel_scale"


def sensor_signals(t, signals, car):
    signals["ay"] = 0.94 * signals["ay"]
    return signals
