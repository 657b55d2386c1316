"""The vehicle file (TOML): what the user measured, plus optional calibration.

Required top-level keys: ``name``, ``mass`` [kg], ``a``, ``b`` [m, CG to front /
rear axle]. Optional tables:

```toml
[steering]            # servo pulse -> front road-wheel angle
center_us = 1500      # pulse width at straight ahead [us]
us_per_rad = 1145.9   # pulse change per radian of road-wheel angle (left positive)

[wheel]
radius = 0.045        # m, of the wheel carrying the hall magnet
pulses_per_rev = 1

[sensors]             # written by `stid calibrate`
accel_offset = [0.0, 0.0, 0.0]    # m/s^2, subtracted after datasheet conversion (x, y, z)
gyro_zero_v = 1.65                # V at zero yaw rate
mount_roll = 0.0                  # rad, accelerometer mounting rotation about x
mount_pitch = 0.0                 # rad, about y
accel_bandwidth_hz = 50.0         # ADXL335 output filter (5 uF / C; 0.1 uF -> 50 Hz); 0 = none
gyro_bandwidth_hz = 88.0          # LISY300AL internal low-pass

[params]              # initial values / bounds of model parameters, e.g.
Cf = { init = 400.0, min = 20.0, max = 5000.0 }
```
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from stid.errors import InputError

DEFAULT_STEER_CENTER_US = 1500.0
DEFAULT_STEER_US_PER_RAD = 500.0 / math.radians(25.0)  # a typical RC servo: +-500 us for +-25 deg


@dataclass
class Vehicle:
    name: str
    mass: float
    a: float
    b: float
    steer_center_us: float = DEFAULT_STEER_CENTER_US
    steer_us_per_rad: float = DEFAULT_STEER_US_PER_RAD
    wheel_radius: float = 0.045
    pulses_per_rev: int = 1
    sensors: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    path: str | None = None
    raw: dict = field(default_factory=dict)

    @property
    def L(self) -> float:
        return self.a + self.b


def _number(doc, key, where, positive=True):
    if key not in doc:
        raise InputError(f"{where} has no '{key}': add it (e.g. {key} = {'9.31' if key == 'mass' else '0.25'}, "
                         f"in {'kg' if key == 'mass' else 'm'})")
    v = doc[key]
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a number, got {v!r}")
    if positive and v <= 0:
        raise InputError(f"{where}: '{key}' must be positive, got {v}")
    return float(v)


def load_vehicle(path) -> Vehicle:
    path = Path(path)
    if not path.exists():
        raise InputError(f"vehicle file {path} does not exist")
    try:
        doc = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"vehicle file {path} is not valid TOML: {e}") from None
    where = f"vehicle file {path}"
    mass = _number(doc, "mass", where)
    a = _number(doc, "a", where)
    b = _number(doc, "b", where)
    if mass > 5000 or a > 10 or b > 10:
        raise InputError(f"{where}: mass {mass} kg, a {a} m, b {b} m look implausible; "
                         "units are kg and m (not g or mm)")
    st = doc.get("steering", {})
    wh = doc.get("wheel", {})
    v = Vehicle(name=str(doc.get("name", path.stem)), mass=mass, a=a, b=b,
                steer_center_us=float(st.get("center_us", DEFAULT_STEER_CENTER_US)),
                steer_us_per_rad=float(st.get("us_per_rad", DEFAULT_STEER_US_PER_RAD)),
                wheel_radius=float(wh.get("radius", 0.045)), pulses_per_rev=int(wh.get("pulses_per_rev", 1)),
                sensors=dict(doc.get("sensors", {})), params=dict(doc.get("params", {})), path=str(path),
                raw=doc)
    if v.steer_us_per_rad == 0:
        raise InputError(f"{where}: steering.us_per_rad must not be 0")
    return v


def default_vehicle() -> Vehicle:
    """The reference 1:8 car, for files loaded without a vehicle file."""
    return Vehicle(name="reference 1:8 car", mass=9.31, a=0.2326, b=0.2874)
