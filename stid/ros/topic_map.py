"""The vehicle file's ``[ros]`` table, and which topic of a bag plays which part.

```toml
[ros]
imu = "/sensors/imu/raw"       # sensor_msgs/Imu: ay (and ax) and the yaw rate r
odometry = "/odom"             # nav_msgs/Odometry: the forward speed vx (twist.linear.x)
steering = "/ackermann_drive"  # ackermann_msgs/AckermannDriveStamped (steering_angle, rad), or a
                               # std_msgs/Float64 servo command (needs [steering] offset, gain)
imu_axes = ["y", "-x", "z"]    # the car's x, y, z as the IMU's axes (here: IMU turned 90 deg)
accel_unit = "m/s^2"           # or "g" (the VESC driver's sensors/imu/raw)
gyro_unit = "rad/s"            # or "deg/s" (the VESC driver's sensors/imu/raw)
stamps = "header"              # or "receive": time messages by the bag's receive times
rate_hz = 100.0                # the run's grid; the IMU's own rate when not given
steering_scale = 1.0           # road-wheel angle per steering_angle: 0.0174533 (degrees), -1 (positive right)
speed_scale = 1.0              # forward speed per twist.linear.x: -1 (a speed_to_erpm_gain of the wrong sign)

[ros.fields]                   # one CSV per topic (stid.ros.topic_files): field = column
stamp = "s + ns * 1e-9"
```

A topic left out is found by its type: the one topic of that type, or among several
the usual F1TENTH name (``f1tenth_system``: ``sensors/imu/raw``, ``odom``,
``ackermann_drive``, the VESC's ``commands/servo/position``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from stid.errors import InputError, unknown_key
from stid.ros.message_types import ACKERMANN, FLOAT64, IMU, ODOMETRY

KEYS = ("imu", "odometry", "steering", "imu_axes", "accel_unit", "gyro_unit", "stamps", "rate_hz", "steering_scale",
        "speed_scale", "fields")
TOPIC_KEYS = ("imu", "odometry", "steering")
UNITS = {"accel_unit": ("m/s^2", "g"), "gyro_unit": ("rad/s", "deg/s"), "stamps": ("header", "receive")}
AXES = ("x", "y", "z", "-x", "-y", "-z")

# the usual names, preferred in this order when a bag has several topics of one type
DEFAULT_TOPICS = {
    "imu": ("/sensors/imu/raw", "/imu", "/imu/data", "/imu/data_raw", "/vesc/sensors/imu/raw"),
    "odometry": ("/odom", "/vesc/odom", "/ego_racecar/odom"),
    # the ackermann_mux's output first: what the car was told, whoever drove
    "ackermann": ("/ackermann_drive", "/ackermann_cmd", "/vesc/high_level/ackermann_cmd_mux/output",
                  "/vesc/low_level/ackermann_cmd_mux/output", "/drive", "/teleop"),
    # std_msgs/Float64 is any number; only these names are taken for a servo command
    "servo": ("/commands/servo/position", "/vesc/commands/servo/position", "/sensors/servo_position_command",
              "/vesc/sensors/servo_position_command"),
}
ROLE_TYPES = {"imu": (IMU,), "odometry": (ODOMETRY,), "steering": (ACKERMANN, FLOAT64)}
ROLE_WORDS = {"imu": "IMU", "odometry": "odometry", "steering": "steering command"}


def check_table(table: dict, where: str) -> None:
    """Raise InputError for a key or value of ``[ros]`` that stid would not use."""

    for key, value in table.items():
        if key not in KEYS:
            raise unknown_key(where, "key", key, list(KEYS), "[ros]")
        if key in TOPIC_KEYS:
            if not isinstance(value, str) or not value:
                raise InputError(f"{where}: [ros] {key} must be a topic name, e.g. {key} = "
                                 f"\"{DEFAULT_TOPICS.get(key, DEFAULT_TOPICS['ackermann'])[0]}\", got {value!r}")
        elif key in UNITS:
            if value not in UNITS[key]:
                raise InputError(f"{where}: [ros] {key} must be one of {', '.join(repr(u) for u in UNITS[key])}, "
                                 f"got {value!r}")
        elif key == "rate_hz":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise InputError(f"{where}: [ros] rate_hz must be a positive number [Hz], got {value!r}")
        elif key == "steering_scale":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value == 0:
                raise InputError(f"{where}: [ros] steering_scale must be a number, the road-wheel angle [rad] per unit "
                                 f"of the AckermannDrive steering_angle (0.0174533 for degrees, -1 for positive "
                                 f"right), got {value!r}")
        elif key == "speed_scale":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value == 0:
                raise InputError(f"{where}: [ros] speed_scale must be a number, the forward speed [m/s] per unit of "
                                 f"the odometry's twist.linear.x (-1 for a speed whose sign is the other way), got "
                                 f"{value!r}")
        elif key == "imu_axes":
            axes_matrix(value, where)
        elif key == "fields":
            _check_fields(value, where)


def _check_fields(fields, where) -> None:
    """[ros.fields] (topic CSVs, stid.ros.topic_files): message field -> column or expression."""
    from stid.ros.message_types import FIELDS

    known = ["stamp"] + sorted({f for fs in FIELDS.values() for f in fs if not f.startswith("header.")})
    if not isinstance(fields, dict):
        raise InputError(f"{where}: [ros] fields must be a table ([ros.fields]), got {fields!r}")
    for key, value in fields.items():
        if key not in known:
            raise unknown_key(where, "field", key, known, "[ros.fields]")
        if not isinstance(value, str) or not value.strip():
            raise InputError(f"{where}: [ros.fields] \"{key}\" must be a column name or expression in quotes, "
                             f"got {value!r}")


def axes_matrix(axes, where: str = "vehicle file"):
    """The 3x3 matrix M with body = M @ imu, from ``imu_axes`` (the car's x, y, z written as
    the IMU's signed axes). It must be a rotation: a mirror is a sign written wrong."""
    import numpy as np

    ok = isinstance(axes, list) and len(axes) == 3 and all(isinstance(a, str) and a.strip() in AXES for a in axes)
    if not ok:
        raise InputError(f"{where}: [ros] imu_axes must be three of {', '.join(AXES)} (the car's x, y, z as the "
                         f"IMU's axes), e.g. [\"y\", \"-x\", \"z\"] for an IMU turned 90 deg, got {axes!r}")
    m = np.zeros((3, 3))
    for row, a in enumerate(axes):
        a = a.strip()
        m[row, "xyz".index(a[-1])] = -1.0 if a.startswith("-") else 1.0
    if abs(abs(np.linalg.det(m)) - 1) > 1e-9:
        raise InputError(f"{where}: [ros] imu_axes {axes!r} uses one IMU axis twice; each of x, y, z once")
    if np.linalg.det(m) < 0:
        raise InputError(f"{where}: [ros] imu_axes {axes!r} is a mirror image, not a mounting: one sign is wrong "
                         "(ISO 8855 and ROS both use right-handed axes: x forward, y left, z up)")
    return m


@dataclass
class Choice:
    imu: str
    odometry: str
    steering: str
    steering_type: str
    notes: list = field(default_factory=list)


def choose(topics: dict, table: dict, servo_map: bool, where: str, listing: str) -> Choice:
    """The topic of each part. ``topics``: ``{name: Topic}``; ``servo_map``: the vehicle file
    declares [steering] offset and gain (a servo command can be used)."""
    notes = []
    imu = _one(topics, "imu", table, where, listing, DEFAULT_TOPICS["imu"])
    odom = _one(topics, "odometry", table, where, listing, DEFAULT_TOPICS["odometry"])
    if "steering" in table:
        steer = _named(topics, "steering", table["steering"], where, listing)
    else:
        acks = [n for n, t in topics.items() if t.msgtype == ACKERMANN]
        servos = [n for n in DEFAULT_TOPICS["servo"] if n in topics and topics[n].msgtype == FLOAT64]
        if servos and (servo_map or not acks):
            steer = servos[0]
        elif acks:
            steer = _prefer(acks, DEFAULT_TOPICS["ackermann"], "steering", where, listing)
            if servos:
                notes.append(f"steer from {steer} (a command in rad); {servos[0]}, the servo command the VESC "
                             "received, is also in the bag: declare [steering] offset and gain to use it")
        else:
            raise InputError(f"{where} has no steering command (ackermann_msgs/msg/AckermannDriveStamped, or a "
                             f"std_msgs/msg/Float64 servo command on {DEFAULT_TOPICS['servo'][0]}); its topics: "
                             f"{listing}. Record the command too, or name it with [ros] steering = \"/topic\"")
    return Choice(imu, odom, steer, topics[steer].msgtype, notes)


def _one(topics, role, table, where, listing, preferred) -> str:
    if role in table:
        return _named(topics, role, table[role], where, listing)
    types = ROLE_TYPES[role]
    found = [n for n, t in topics.items() if t.msgtype in types]
    if not found:
        raise InputError(f"{where} has no {ROLE_WORDS[role]} topic ({' or '.join(types)}); its topics: {listing}. "
                         f"Record it too, or name it with [ros] {role} = \"/topic\" if it is there")
    return _prefer(found, preferred, role, where, listing)


def _prefer(found, preferred, role, where, listing) -> str:
    if len(found) == 1:
        return found[0]
    for name in preferred:
        if name in found:
            return name
    raise InputError(f"{where} has several {ROLE_WORDS[role]} topics ({', '.join(sorted(found))}): name the one to "
                     f"use in the vehicle file, [ros] {role} = \"{sorted(found)[0]}\"")


def _named(topics, role, name, where, listing) -> str:
    if name not in topics:
        raise InputError(f"[ros] {role} = \"{name}\": {where} has no such topic; its topics: {listing}")
    got = topics[name].msgtype
    if got not in ROLE_TYPES[role]:
        same = [n for n, t in topics.items() if t.msgtype in ROLE_TYPES[role]]
        raise InputError(f"[ros] {role} = \"{name}\" is a {got} topic, a message type stid does not read as the "
                         f"{ROLE_WORDS[role]} (it reads {' or '.join(ROLE_TYPES[role])}; topics of that type in "
                         f"{where}: {', '.join(same) if same else 'none'})")
    return name
