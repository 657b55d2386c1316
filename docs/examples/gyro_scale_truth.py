"""The simulated car's side: its gyro reads 6% high (written without stid)."""

NAME = "gyro_scale"


def sensor_signals(t, signals, car):
    signals["r"] = 1.06 * signals["r"]
    return signals
