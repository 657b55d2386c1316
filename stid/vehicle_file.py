"""The vehicle file (TOML): what the user measured, plus optional calibration.

Required top-level keys: ``mass`` [kg], ``a``, ``b`` [m, CG to front /
rear axle]; ``name`` is optional (the file's name otherwise). Optional tables:

```toml
[steering]            # servo pulse -> front road-wheel angle
center_us = 1500      # pulse width at straight ahead [us]
us_per_rad = 1145.9   # pulse change per radian of road-wheel angle (left positive)
offset = 0.5304       # a servo command in other units (0-1, +-1) at straight ahead ...
gain = -1.2135        # ... and its change per radian: command = offset + gain * angle

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
accel_filter_order = 1            # 1: first-order (RC); 2: second-order Butterworth (an IMU's digital filter)

[params]              # start / bounds of model parameters in every fit (docs/params_in_the_vehicle_file.md)
Cf = { init = 400.0, min = 20.0, max = 5000.0 }

[csv]                 # a CSV not in the contract: contract column = source column or expression
t = "time_ms * 0.001"
ay = "-imu_ax"

[ros]                 # ROS bags: topics and the IMU's mounting (docs/ros.md)
imu = "/sensors/imu/raw"
imu_axes = ["y", "-x", "z"]

[targets]             # `stid live`: the 95% half-width each parameter should reach [% of its value]
Iz = "3%"
```

``gyro_v_per_dps`` (gyro sensitivity [V per deg/s]) may also be set in ``[sensors]``.
A sensor bandwidth of 0 means no filter. ``[params]`` names parameters of the base
models (``Cf``, ``Cr``, ``Iz``; greybox ``Cx``, ``Cy``, ``CA``) or of a registered
effect; every fit starts at its ``init`` and searches within its ``min``/``max`` (a fit
that ends on a bound gives no interval), the closed-form steady-state lines excepted;
``[targets]`` keys are parameters too (``stid live``). ``[csv]`` keys are contract columns (stid.csv_map), ``[ros]`` keys are listed in
stid.ros.topic_map. Any other key or table is an error that names it and the nearest known key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from stid.errors import InputError, unknown_key

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
    csv: dict = field(default_factory=dict)
    ros: dict = field(default_factory=dict)
    targets: dict = field(default_factory=dict)  # parameter -> 95% half-width [% of value] (stid live)
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


# Every key the code reads (stid/convert.py, calibrate.py, models/, fit/, plan.py, cli.py).
# A key nobody reads would be silently ignored, so it is an error instead.
TOP_KEYS = ("name", "mass", "a", "b")
TABLES = {
    "steering": ("center_us", "us_per_rad", "offset", "gain"),
    "wheel": ("radius", "pulses_per_rev"),
    "sensors": ("accel_offset", "gyro_zero_v", "gyro_v_per_dps", "mount_roll", "mount_pitch",
                "accel_bandwidth_hz", "gyro_bandwidth_hz", "accel_filter_order", "gyro_filter_order"),
    "params": None,  # model parameter names: checked against the models (_check_params)
    "board": None,  # the board's HELLO, declared for a log none reached (host/hello_supply.py checks it)
    "csv": None,  # contract column -> source expression (stid.csv_map checks it)
    "ros": None,  # topics and IMU mounting of ROS bags (stid.ros.topic_map checks it)
    "targets": None,  # parameter -> precision in percent, for stid live (stid.live.targets checks it)
}
PARAM_SPEC_KEYS = ("init", "min", "max")
_NONNEGATIVE = ("accel_bandwidth_hz", "gyro_bandwidth_hz")  # Hz; 0 = no filter


def _check_keys(doc, where) -> None:
    for key, value in doc.items():
        if key in TABLES:
            if not isinstance(value, dict):
                raise InputError(f"{where}: '{key}' must be a table ([{key}]), got {value!r}")
            continue
        if key not in TOP_KEYS:
            if isinstance(value, dict):
                raise unknown_key(where, "table", f"[{key}]", [f"[{t}]" for t in TABLES])
            raise unknown_key(where, "key", key, list(TOP_KEYS) + [f"[{t}]" for t in TABLES])
    for table, keys in TABLES.items():
        if keys is None or table not in doc:
            continue
        for key, value in doc[table].items():
            if key not in keys:
                raise unknown_key(where, "key", key, list(keys), f"[{table}]")
            if key == "accel_offset":
                ok = isinstance(value, list) and len(value) == 3 and all(_is_number(x) for x in value)
                if not ok:
                    raise InputError(f"{where}: [sensors] accel_offset must be three numbers [x, y, z] in m/s^2, "
                                     f"got {value!r}")
            elif not _is_number(value):
                raise InputError(f"{where}: [{table}] {key} must be a number, got {value!r}")
            elif key in _NONNEGATIVE and value < 0:
                raise InputError(f"{where}: [{table}] {key} must be 0 (no filter) or a bandwidth in Hz, got {value}")
            elif key.endswith("_filter_order") and value not in (1, 2):
                raise InputError(f"{where}: [{table}] {key} must be 1 (a first-order low-pass: an RC filter, the "
                                 f"ADXL335's capacitor) or 2 (a second-order Butterworth: many IMUs' digital "
                                 f"low-pass), got {value}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _known_params() -> list:
    # Imported only when a file names parameters: the model catalogue costs most of a second.
    from stid.models.bicycle import BASE_PARAMS
    from stid.models.effect import available_effects
    from stid.models.greybox import GREYBOX_PARAMS

    known = [p.name for p in BASE_PARAMS]
    known += [p.name for p in GREYBOX_PARAMS if p.name not in known]
    for cls in available_effects().values():
        known += [p.name for p in cls.params if p.name not in known]
    return known


def _check_targets(targets: dict, where) -> dict:
    """[targets] entries: a model parameter and its precision in percent (``Iz = "3%"``)."""
    if not targets:
        return {}
    from stid.live.targets import parse_percent

    known = _known_params()
    out = {}
    for name, value in targets.items():
        if name not in known:
            raise unknown_key(where, "parameter", name, known, "[targets]")
        out[name] = parse_percent(value, f"{where}: [targets] {name}")
    return out


def _check_params(params: dict, where, vehicle=None) -> None:
    """[params] entries are model parameters: ``NAME = { init = .., min = .., max = .. }``, each
    a range that holds its start (with the catalogue's values for what it leaves out) and, for a
    parameter fitted in log space (positive), no bound at or below 0."""
    if not params:
        return
    from stid.models.bicycle import BASE_PARAMS
    from stid.models.effect import available_effects
    from stid.models.greybox import GREYBOX_PARAMS

    known = _known_params()
    for name, spec in params.items():
        if name not in known:
            raise unknown_key(where, "parameter", name, known, "[params]")
        if not isinstance(spec, dict):
            raise InputError(f"{where}: [params] {name} must be a table, e.g. {name} = {{ init = 1.0, min = 0.1, "
                             f"max = 10.0 }}, got {spec!r}")
        for key, value in spec.items():
            if key not in PARAM_SPEC_KEYS:
                raise unknown_key(where, "key", key, list(PARAM_SPEC_KEYS), f"[params] {name}")
            if not _is_number(value):
                raise InputError(f"{where}: [params] {name}.{key} must be a number, got {value!r}")
        if vehicle is not None:
            for q in _definitions(name, BASE_PARAMS, GREYBOX_PARAMS, available_effects()):
                _check_range(q, vehicle, where)


def _definitions(name, base, greybox, effects) -> list:
    """Every catalogue parameter called ``name`` (the bicycle's Iz and the grey-box's are two)."""
    found = [q for q in list(base) + list(greybox) if q.name == name]
    return found + [q for cls in effects.values() for q in cls.params if q.name == name]


def _check_range(q, vehicle, where) -> None:
    lo, hi, init = (q.value(a, vehicle) for a in ("lower", "upper", "init"))
    mine = vehicle.params[q.name]
    said = ", ".join(f"{k} = {mine[k]:g}" for k in PARAM_SPEC_KEYS if k in mine)
    theirs = f"(catalogue: init {q.catalogue('init', vehicle):.4g}, min {q.catalogue('lower', vehicle):.4g}, " \
             f"max {q.catalogue('upper', vehicle):.4g} {q.unit})"
    if q.log and lo <= 0:
        raise InputError(f"{where}: [params] {q.name} ({said}): its min must be above 0, since {q.name} is positive "
                         f"and fitted in log space {theirs}")
    if not lo < hi:
        raise InputError(f"{where}: [params] {q.name} ({said}) leaves no range: min {lo:.4g} is not below max {hi:.4g} "
                         f"{theirs}; give both, min below max")
    if not lo <= init <= hi:
        raise InputError(f"{where}: [params] {q.name} ({said}): the start {init:.4g} lies outside [{lo:.4g}, {hi:.4g}] "
                         f"{theirs}; give an init inside the range")


# kg per cubic metre of wheelbase: a car's mass is about 100 x its wheelbase cubed (a 1:8 RC car
# 3.5 kg at 0.33 m: 97; a saloon 1500 kg at 2.7 m: 76; a lorry 40 t at 5 m: 320), and no vehicle
# is denser than steel (7850 kg/m^3) filling a box of L x L/2 x L/2 (~2000 L^3)
DENSEST = 2000.0


def load_vehicle(path) -> Vehicle:
    path = Path(path)
    if not path.exists():
        raise InputError(f"vehicle file {path} does not exist")
    if path.is_dir():
        raise InputError(f"vehicle file {path} is a directory: give the car's TOML file (e.g. "
                         "docs/examples/rc8.toml)")
    try:
        raw = path.read_bytes()
        if raw[:5] == b"\x89MCAP":  # the commonest slip: a run given as --vehicle
            raise InputError(f"{path} is a logged run (MCAP), not a vehicle file: give the car's TOML file "
                             "with --vehicle (e.g. docs/examples/rc8.toml) and the runs before it")
        doc = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"vehicle file {path} is not valid TOML: {e}") from None
    where = f"vehicle file {path}"
    _check_keys(doc, where)
    mass = _number(doc, "mass", where)
    a = _number(doc, "a", where)
    b = _number(doc, "b", where)
    odd = [f"{k} {v:g} {unit}" for k, v, unit, most in (("mass", mass, "kg", 5000), ("a", a, "m", 10),
                                                         ("b", b, "m", 10)) if v > most]
    if odd:
        raise InputError(f"{where}: {', '.join(odd)} look{'s' if len(odd) == 1 else ''} implausible; "
                         "units are kg and m (not g or mm)")
    wheelbase = a + b
    if wheelbase > 0 and mass > DENSEST * wheelbase ** 3:
        # (a mass in grams passed the 5000 limit above for any car under 5 kg, and every stiffness and
        # the inertia then came out 1000 times too large, without a word)
        raise InputError(f"{where}: mass {mass:g} kg for a wheelbase of {wheelbase:g} m is heavier than a block "
                         f"of solid steel that size; units are kg and m (a mass in grams?)")
    st = doc.get("steering", {})
    wh = doc.get("wheel", {})
    v = Vehicle(name=str(doc.get("name", path.stem)), mass=mass, a=a, b=b,
                steer_center_us=float(st.get("center_us", DEFAULT_STEER_CENTER_US)),
                steer_us_per_rad=float(st.get("us_per_rad", DEFAULT_STEER_US_PER_RAD)),
                wheel_radius=float(wh.get("radius", 0.045)), pulses_per_rev=int(wh.get("pulses_per_rev", 1)),
                sensors=dict(doc.get("sensors", {})), params=dict(doc.get("params", {})),
                csv=dict(doc.get("csv", {})), ros=dict(doc.get("ros", {})), path=str(path), raw=doc)
    if v.steer_us_per_rad == 0:
        raise InputError(f"{where}: steering.us_per_rad must not be 0")
    if ("gain" in st) != ("offset" in st):
        have, lack = ("gain", "offset") if "gain" in st else ("offset", "gain")
        raise InputError(f"{where}: [steering] has {have} but no {lack}: a servo command maps to the road-wheel "
                         "angle by both (command = offset + gain * angle [rad])")
    if st.get("gain") == 0:
        raise InputError(f"{where}: [steering] gain must not be 0 (command change per radian of road-wheel angle)")
    _check_params(v.params, where, v)
    v.targets = _check_targets(doc.get("targets", {}), where)
    from stid.csv_map import check_table
    from stid.ros.topic_map import check_table as check_ros

    check_table(v.csv, where)
    check_ros(v.ros, where)
    return v


def default_vehicle() -> Vehicle:
    """The reference 1:8 car, for files loaded without a vehicle file."""
    return Vehicle(name="reference 1:8 car", mass=9.31, a=0.2326, b=0.2874)
