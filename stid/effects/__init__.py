"""The catalogue of physical effects. Importing this package registers them."""

from stid.effects import (  # noqa: F401
    accel_offset,
    actuator_lag,
    body_roll,
    gyro_scale,
    locked_diff,
    sensor_bias,
    sensor_delay,
    steer_offset,
    steering_nonlinearity,
    tyre_relaxation,
    tyre_saturation,
)
