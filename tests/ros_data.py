"""A small F1TENTH-class car driven in plain physics, and the bags its ROS stack would
record, written with rosbags' own writers (ROS 2 MCAP and ROS 1).

The car is a linear single-track model written here (not stid's), integrated at 1 kHz
with RK4; the steering command is held between the 50 Hz commands, as a servo holds it
(and the road wheel follows it through the servo's first-order lag, with ``servo_tau``).
The run stands still for 3 s, speeds up to ~3 m/s, then is steered at random. The IMU
samples ``imu_offset_ms`` after each command's instant (not on it: a car's clocks are not
locked to each other).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

M, A, B, IZ, CF, CR = 3.5, 0.15, 0.18, 0.05, 90.0, 110.0  # kg, m, m, kg m^2, N/rad per axle
L = A + B
G = 9.81
BASE_HZ = 1000
# the VESC's servo map on an F1TENTH car (f1tenth_system vesc.yaml): servo = gain * angle + offset
SERVO_GAIN, SERVO_OFFSET = -1.2135, 0.5304
EPOCH_NS = 1_700_000_000_000_000_000  # header stamps are wall-clock time
RECEIVE_MS = 1.25  # each message reaches the recorder this long after it was measured (whole quarters of a ms)


@dataclass
class Drive:
    """The truth at 1 kHz and what each sensor measured at its own instants."""

    t: np.ndarray
    steer: np.ndarray  # the held command [rad], on [t, t + 1 ms) (the road-wheel angle without a servo lag)
    vx: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    cmd_t: np.ndarray  # command instants [s] and angles [rad]
    cmd: np.ndarray
    imu_k: np.ndarray = field(default=None)  # indices of the IMU samples into t
    odom_k: np.ndarray = field(default=None)
    imu_ay: np.ndarray = field(default=None)  # body-frame measurements (with noise)
    imu_ax: np.ndarray = field(default=None)
    imu_r: np.ndarray = field(default=None)
    odom_vx: np.ndarray = field(default=None)
    wheel: np.ndarray = field(default=None)  # the road-wheel angle [rad] at each t (steer through the servo)


def drive(duration=40.0, seed=0, imu_hz=200, odom_hz=50, cmd_hz=50, steer_rms=0.06, noise=True,
          imu_offset_ms=2, servo_tau=0.0, dead_ms=0) -> Drive:
    rng = np.random.default_rng(seed)
    n = int(duration * BASE_HZ)
    t = np.arange(n) / BASE_HZ
    vx = np.where(t < 3.0, 0.0, np.minimum((t - 3.0) / 2.0, 1.0) * (3.0 + 0.5 * np.sin(2 * np.pi * (t - 3.0) / 20)))
    cmd_t = np.arange(0.0, duration, 1.0 / cmd_hz)
    # random steering, band-limited to ~4 Hz by a moving average of white noise, from t = 6 s
    raw = rng.standard_normal(len(cmd_t) + 20)
    smooth = np.convolve(raw, np.ones(6) / 6, mode="same")[10:-10]
    cmd = np.where(cmd_t >= 6.0, smooth / smooth.std() * steer_rms, 0.0)
    # held from each command's millisecond on (whole milliseconds: the staircase is exact at 1 kHz)
    steer = cmd[np.searchsorted(np.round(cmd_t * BASE_HZ).astype(int), np.arange(n), side="right") - 1]
    # the wheel acts on each command dead_ms after its stamp (the driver, the servo's frame)
    wheel = np.concatenate([np.full(dead_ms, steer[0]), steer[:n - dead_ms]]) if dead_ms else steer
    acting = wheel
    if servo_tau > 0:  # the servo's first-order lag, exact for an input held over each millisecond
        wheel = np.empty(n)
        w, keep = 0.0, math.exp(-1.0 / (BASE_HZ * servo_tau))
        for k in range(n):
            wheel[k] = w
            w = acting[k] + (w - acting[k]) * keep
    vy, r, ay = _integrate(t, vx, wheel, continuous=servo_tau > 0)
    d = Drive(t=t, steer=steer, vx=vx, ay=ay, r=r, cmd_t=cmd_t, cmd=cmd, wheel=wheel)
    d.imu_k = np.arange(imu_offset_ms, n, BASE_HZ // imu_hz)  # the IMU off the command's instants
    d.odom_k = np.arange(7, n, BASE_HZ // odom_hz)
    s = 1.0 if noise else 0.0
    d.imu_ay = ay[d.imu_k] + s * 0.05 * rng.standard_normal(len(d.imu_k))
    d.imu_ax = s * 0.05 * rng.standard_normal(len(d.imu_k))
    d.imu_r = r[d.imu_k] + s * 0.005 * rng.standard_normal(len(d.imu_k))
    d.odom_vx = vx[d.odom_k] + s * 0.02 * rng.standard_normal(len(d.odom_k))
    return d


def _integrate(t, vx, steer, continuous=False):
    """vy, r, ay of the linear single-track model (RK4; steer held over each step, or with
    ``continuous`` a line from its value at the step's start to the next)."""
    dt = 1.0 / BASE_HZ
    n = len(t)
    vy_out, r_out, ay_out = np.zeros(n), np.zeros(n), np.zeros(n)
    vy = r = 0.0

    def deriv(vy, r, v, d):
        ff = CF * (d - (vy + A * r) / v)
        fr = CR * (-(vy - B * r) / v)
        return (ff + fr) / M - v * r, (A * ff - B * fr) / IZ, (ff + fr) / M

    for k in range(n):
        v, d = float(vx[k]), float(steer[k])
        d1 = float(steer[min(k + 1, n - 1)]) if continuous else d
        if v < 0.3:  # standing (or barely rolling) and not steered: nothing moves sideways
            vy = r = 0.0
            continue
        k1 = deriv(vy, r, v, d)
        k2 = deriv(vy + 0.5 * dt * k1[0], r + 0.5 * dt * k1[1], v, 0.5 * (d + d1))
        k3 = deriv(vy + 0.5 * dt * k2[0], r + 0.5 * dt * k2[1], v, 0.5 * (d + d1))
        k4 = deriv(vy + dt * k3[0], r + dt * k3[1], v, d1)
        vy_out[k], r_out[k], ay_out[k] = vy, r, k1[2]
        vy += dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        r += dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return vy_out, r_out, ay_out


def sample_means(d: Drive, k: np.ndarray, period_ms: float, late_ms: float = 0.0) -> np.ndarray:
    """The held command's mean over the sample period centred on each instant ``t[k]``, as the
    contract asks of a held command (docs/ros.md); ``late_ms``: of the staircase as timed that
    much late (a topic timed by its receive times). Counted here in quarter milliseconds: the
    staircase steps only on whole ones and the periods' ends (+-2.5 ms at 200 Hz, 5 ms at 100 Hz)
    and the delays fall on quarters, so each quarter is one value and the mean is exact."""
    quarters, late = int(round(period_ms * 4)), int(round(late_ms * 4))
    assert abs(quarters - period_ms * 4) < 1e-9 and abs(late - late_ms * 4) < 1e-9, "not whole quarters of a ms"
    at = k[:, None] * 4 - late - quarters / 2 + 0.5 + np.arange(quarters)[None, :]  # quarter midpoints
    ms = np.clip(np.floor(at / 4).astype(int), 0, len(d.steer) - 1)
    return d.steer[ms].mean(axis=1)


def contract_columns(d: Drive) -> dict:
    """The import contract's columns: on the IMU's instants, the held command's mean over each
    sample period, the odometry's speed interpolated."""
    t = d.t[d.imu_k]
    period_ms = float(np.median(np.diff(d.imu_k))) * 1000 / BASE_HZ
    return {"t": t, "steer": sample_means(d, d.imu_k, period_ms), "ay": d.imu_ay, "r": d.imu_r,
            "vx": np.interp(t, d.t[d.odom_k], d.odom_vx)}


def contract_csv(d: Drive, path: Path) -> Path:
    """The same measurements as the import contract's CSV (``contract_columns``)."""
    cols = contract_columns(d)
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="",
               fmt="%.9g")
    return path


def vehicle_toml(path: Path, extra: str = "") -> Path:
    path.write_text(f"name = \"f1tenth-class test car\"\nmass = {M}\na = {A}\nb = {B}\n{extra}")
    return path


# -- bags ----------------------------------------------------------------------------------

_ACK_DRIVE = "float32 steering_angle\nfloat32 steering_angle_velocity\nfloat32 speed\nfloat32 acceleration\nfloat32 jerk\n"
_ACK_STAMPED = "std_msgs/Header header\nackermann_msgs/AckermannDrive drive\n"


def typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = get_types_from_msg(_ACK_DRIVE, "ackermann_msgs/msg/AckermannDrive")
    types.update(get_types_from_msg(_ACK_STAMPED, "ackermann_msgs/msg/AckermannDriveStamped"))
    ts.register(types)
    return ts


@dataclass
class Layout:
    """How the car's ROS stack published the drive."""

    imu_topic: str = "/sensors/imu/raw"
    odom_topic: str = "/odom"
    steer_topic: str = "/ackermann_drive"
    servo: bool = False  # steer as the VESC's 0-1 servo command (std_msgs/Float64, no header)
    imu_to_body: tuple = ("x", "y", "z")  # the car's x, y, z as the IMU's signed axes ([ros] imu_axes)
    gravity: bool = True  # the accelerometer holds gravity (raw), or has it removed
    tilt_roll_deg: float = 0.0  # the IMU's board rolled about the car's x axis
    accel_g: bool = False  # accelerometer in g, gyro in deg/s (the VESC driver's sensors/imu/raw)
    gyro_bias: float = 0.0  # rad/s
    odom_yaw_sign: float = 1.0  # the odometry's (unused) yaw rate, -1: opposite to the gyro
    stamp_offset_s: dict = field(default_factory=dict)  # topic -> shift of its header stamps
    drop_topics: tuple = ()
    backwards_at: int | None = None  # an IMU stamp that goes back
    nan_at: int | None = None  # an IMU message whose ay is NaN (a driver's failed read)
    extra_topics: dict = field(default_factory=dict)  # topic -> msgtype, a few messages each
    steer_deg: bool = False  # the Ackermann steering_angle published in degrees (a driver's mistake)
    imu_silent_s: tuple = ()  # (from, to) [s]: the IMU driver published nothing then (it stalled)
    imu_stamp_jitter_s: float = 0.0  # rms of a random error in each IMU header stamp (the sample is on time)
    imu_lost_every: int = 0  # every so many IMU messages one is lost (never reaches the bag)
    # the odometry's twist in the world's frame (child_frame_id "odom", against REP 105), the car
    # heading this many radians from the world's x at the start (None: in the car's frame)
    odom_world_heading: float | None = None


def _imu_axes(layout: Layout, body: np.ndarray) -> np.ndarray:
    """Body-frame vectors (3, n) as the IMU reads them: its board rolled by ``tilt_roll_deg``
    about the car's x axis (the board's axes are the car's turned by Rx: it reads Rx^T v),
    its chip turned on the board per ``imu_to_body``."""
    c, s = math.cos(math.radians(layout.tilt_roll_deg)), math.sin(math.radians(layout.tilt_roll_deg))
    rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    m = np.zeros((3, 3))
    for row, a in enumerate(layout.imu_to_body):
        m[row, "xyz".index(a[-1])] = -1.0 if a.startswith("-") else 1.0
    return m.T @ (rx.T @ body)  # board = m @ chip, m orthogonal


def write_bag(d: Drive, path: Path, layout: Layout = Layout(), ros1: bool = False, sqlite: bool = False,
              compress_messages: bool = False) -> Path:
    """The drive as ``ros2 bag record`` (MCAP storage, or SQLite with ``sqlite``) or ``rosbag
    record`` would hold it; ``compress_messages``: as ``--compression-mode message`` (zstd)."""
    ts = typestore(ros1)
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    V3 = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    imu_cls = ts.types["sensor_msgs/msg/Imu"]
    od = {k: ts.types[f"geometry_msgs/msg/{k}"] for k in ("Pose", "Point", "PoseWithCovariance", "Twist",
                                                          "TwistWithCovariance")}
    odom_cls = ts.types["nav_msgs/msg/Odometry"]
    ack_cls = ts.types["ackermann_msgs/msg/AckermannDriveStamped"]
    drv_cls = ts.types["ackermann_msgs/msg/AckermannDrive"]
    f64 = ts.types["std_msgs/msg/Float64"]
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    seq = [0]

    def header(t, frame, topic):
        ns = EPOCH_NS + int(round((t + layout.stamp_offset_s.get(topic, 0.0)) * 1e9))
        stamp = T(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)
        seq[0] += 1
        return H(seq=seq[0], stamp=stamp, frame_id=frame) if ros1 else H(stamp=stamp, frame_id=frame)

    zero9, zero36 = np.zeros(9), np.zeros(36)
    events = []  # (receive ns, topic, msgtype, message)
    rx = lambda t: EPOCH_NS + int(round((t + RECEIVE_MS / 1000) * 1e9))  # noqa: E731 - the recorder's time
    t_imu = d.t[d.imu_k]
    body_acc = np.vstack([d.imu_ax, d.imu_ay, np.full(len(t_imu), G if layout.gravity else 0.0)])
    body_gyro = np.vstack([np.zeros(len(t_imu)), np.zeros(len(t_imu)), d.imu_r + layout.gyro_bias])
    acc, gyro = _imu_axes(layout, body_acc), _imu_axes(layout, body_gyro)
    if layout.accel_g:
        acc, gyro = acc / G, np.degrees(gyro)
    if layout.nan_at is not None:
        acc[1, layout.nan_at] = np.nan
    jitter = layout.imu_stamp_jitter_s * np.random.default_rng(17).standard_normal(len(t_imu))
    for k, t in enumerate(t_imu):
        if layout.imu_silent_s and layout.imu_silent_s[0] <= t < layout.imu_silent_s[1]:
            continue
        if layout.imu_lost_every and k % layout.imu_lost_every == layout.imu_lost_every - 1:
            continue
        # a stamp that goes back (a clock step in the driver): received in its place all the same
        stamp_t = (t - 0.012 if k == layout.backwards_at else t) + jitter[k]
        m = imu_cls(header=header(stamp_t, "imu_link", layout.imu_topic), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=zero9, angular_velocity=V3(x=gyro[0, k], y=gyro[1, k], z=gyro[2, k]),
                    angular_velocity_covariance=zero9,
                    linear_acceleration=V3(x=acc[0, k], y=acc[1, k], z=acc[2, k]),
                    linear_acceleration_covariance=zero9)
        events.append((rx(t), layout.imu_topic, imu_cls.__msgtype__, m))
    t_od = d.t[d.odom_k]
    yaw_rate = layout.odom_yaw_sign * d.vx[d.odom_k] * np.tan(d.steer[d.odom_k]) / L  # as vesc_to_odom computes it
    child, twist_x, twist_y = "base_link", d.odom_vx, np.zeros(len(t_od))
    if layout.odom_world_heading is not None:  # the body's forward speed turned into the world's axes
        heading = layout.odom_world_heading + np.cumsum(d.r)[d.odom_k] / BASE_HZ
        child, twist_x, twist_y = "odom", d.odom_vx * np.cos(heading), d.odom_vx * np.sin(heading)
    for k, t in enumerate(t_od):
        pose = od["PoseWithCovariance"](pose=od["Pose"](position=od["Point"](x=0.0, y=0.0, z=0.0),
                                                        orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0)),
                                        covariance=zero36)
        tw = od["TwistWithCovariance"](twist=od["Twist"](linear=V3(x=twist_x[k], y=twist_y[k], z=0.0),
                                                         angular=V3(x=0.0, y=0.0, z=yaw_rate[k])), covariance=zero36)
        m = odom_cls(header=header(t, "odom", layout.odom_topic), child_frame_id=child, pose=pose, twist=tw)
        events.append((rx(t), layout.odom_topic, odom_cls.__msgtype__, m))
    for t, a in zip(d.cmd_t, d.cmd):
        if layout.servo:
            m = f64(data=SERVO_GAIN * a + SERVO_OFFSET)
            events.append((rx(t), layout.steer_topic, f64.__msgtype__, m))
        else:
            m = ack_cls(header=header(t, "base_link", layout.steer_topic),
                        drive=drv_cls(steering_angle=float(np.degrees(a)) if layout.steer_deg else a,
                                      steering_angle_velocity=0.0, speed=3.0, acceleration=0.0,
                                      jerk=0.0))
            events.append((rx(t), layout.steer_topic, ack_cls.__msgtype__, m))
    for topic, msgtype in layout.extra_topics.items():
        for k in range(5):
            events.append((rx(k * 0.1), topic, msgtype, _filler(ts, msgtype)))
    events = [e for e in events if e[1] not in layout.drop_topics]
    events.sort(key=lambda e: e[0])
    if ros1:
        from rosbags.rosbag1 import Writer
        w = Writer(path)
    else:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
        w = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3 if sqlite else StoragePlugin.MCAP)
        if compress_messages:
            w.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with w:
        conns = {}
        for _, topic, msgtype, _m in events:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
        for ns, topic, msgtype, m in events:
            w.write(conns[topic], ns, ser(m, msgtype))
    return path


def _filler(ts, msgtype):
    if msgtype == "geometry_msgs/msg/Vector3Stamped":
        T, H, V3 = (ts.types[k] for k in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                                          "geometry_msgs/msg/Vector3"))
        return ts.types[msgtype](header=H(stamp=T(sec=1, nanosec=0), frame_id="x"), vector=V3(x=0.0, y=0.0, z=1.0))
    if msgtype == "std_msgs/msg/String":
        return ts.types[msgtype](data="hello")
    raise ValueError(msgtype)


def split_bag(src: Path, dst_dir: Path, pieces: int = 3, chunk_size: int = 64 * 1024) -> list:
    """The bag's messages in ``pieces`` files split by time, as ``ros2 bag record --max-bag-duration``
    writes them (NAME_0.mcap, NAME_1.mcap, ...; zstd chunks, libmcap-like), without the
    metadata.yaml rosbag2 writes when it stops. Returns the files."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f:
        reader = make_reader(f)
        profile = reader.get_header().profile
        msgs = [(s, c, m) for s, c, m in reader.iter_messages(log_time_order=True)]
    t0, t1 = msgs[0][2].log_time, msgs[-1][2].log_time + 1
    dst_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for k in range(pieces):
        lo, hi = t0 + (t1 - t0) * k // pieces, t0 + (t1 - t0) * (k + 1) // pieces
        path = dst_dir / f"{dst_dir.name}_{k}.mcap"
        with open(path, "wb") as out:
            w = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
            w.start(profile=profile, library="libmcap-like (stid tests)")
            copy = _copier(w)
            for schema, channel, msg in msgs:
                if lo <= msg.log_time < hi:
                    copy(schema, channel, msg)
            w.finish()
        files.append(path)
    return files


def ros2_mcap(bag_dir: Path) -> Path:
    """The .mcap file inside a rosbag2 directory (what a user may give instead of the directory)."""
    (f,) = sorted(bag_dir.glob("*.mcap"))
    return f


def imu_axes_value(layout: Layout) -> str:
    return "[" + ", ".join(f'"{a}"' for a in layout.imu_to_body) + "]"



def as_libmcap_writes(src: Path, dst: Path, chunk_size: int = 768 * 1024, profile: str | None = None) -> Path:
    """The bag's records re-chunked as ``ros2 bag record -s mcap`` writes them (libmcap's
    McapWriterOptions defaults: zstd chunks of 768 KiB with CRCs, a message index after each),
    by the mcap library. rosbags' own writer leaves chunks uncompressed and without CRCs."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        w = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile=reader.get_header().profile if profile is None else profile,
                library="libmcap-like (stid tests)")
        copy = _copier(w)
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            copy(schema, channel, msg)
        w.finish()
    return dst


def _copier(w):
    """``copy(schema, channel, msg)``: a message read from one MCAP written by ``w``, its schema and
    channel registered there the first time."""
    schemas, channels = {}, {}

    def copy(schema, channel, msg):
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                      schemas[schema.id], channel.metadata)
        w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)

    return copy
