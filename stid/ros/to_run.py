"""A ROS bag as runs: the chosen topics timed by their header stamps, cut to the time
all of them cover, brought onto one uniform grid, the IMU turned into the car's axes.

What is done to the data is said in the run's notes: which topic gave what, the grid
and how each signal reached it (measurements interpolated linearly; a command held
until the next one, as the servo holds it), whether the accelerometer holds gravity,
the gyro zero taken from the stand-still.
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import numpy as np

from stid import convert, input_checks, sensor_chain
from stid.errors import InputError
from stid.held_command import interval_means
from stid.ros import topic_map
from stid.ros.bag import Bag, messages_compressed, split_files
from stid.ros.message_types import ACKERMANN, FIELDS, FLOAT64
from stid.run import Run, fine_piece

G = 9.81
# A sensor topic's silence is marked not measured (left out of every cost, the model running
# through it on the known command); a longer one cuts the run: after 0.5 s (several yaw time
# constants) the car's state is forgotten anyway. The command topic's silences cut nothing:
# the servo holds its last command until the next arrives.
SENSOR_CUT_S = 0.5
MIN_SAMPLES = 20
GAP_PERIODS = 2.5  # a step this many median periods long lost messages
MAX_BAD_SHARE = 0.5  # of a topic's messages not a number: beyond it, not a driver's lapse but the wrong topic
# The models draw straight lines between their input's samples: at a slow IMU's rate (30-60 Hz,
# with a 50 Hz command) even the held command's period means (stid.held_command) spread each step
# over a sample period. On exact single-track bags with a 50 ms servo lag that read tau_steer -1%
# at 50 Hz and -3% at 30 Hz, and Cr -0.8%, with intervals that missed them. Below FINE_BELOW_HZ
# the steer is also kept on a grid near FINE_FS (Run.steer_fine), which drives the models; the
# outputs stay at the IMU's own instants.
FINE_BELOW_HZ = 90.0
FINE_FS = 200.0  # the time-domain fit's own rate (stid.fit.dataset.FIT_FS)
# A command whose steps fall at one point of every IMU period (one clock for both, as in a
# simulator) puts the same sub-sample error into every step, where on two clocks the errors average
# out. The period means put each step's integral at its time, not its instant: an output that
# answers the steer at once (ay through the front tyre) and is sampled at an instant reads the step
# early or late by a fixed part of a period. On a trial user's exact bags (200 Hz IMU sampled at an
# instant, 50 Hz command 1.7 ms after it) Cf -1.0%, Cr -1.5%, Iz -1.1%, intervals missing Cr and
# Iz; driven at 1 kHz: +0.02%, -0.16%, +0.01%. Steps this concentrated in phase (LOCKED_SHARE of
# them in the FEW_PHASES fullest of PHASE_BINS parts of the IMU period; one clock at a few points of
# it, as a 21 ms command on a 5 ms IMU, counts too) drive the models on a grid near LOCKED_FS. (An
# IMU that averages over its period reads -1% so, within its intervals.)
LOCKED_SHARE = 0.5
LOCKED_FS = 1000.0
PHASE_BINS, FEW_PHASES = 50, 5  # the steps in the 5 fullest of 50 bins of phase: 10% if spread evenly


def load_bag(path, vehicle) -> list[Run]:
    path = Path(path)
    where = str(path)
    table = vehicle.ros if vehicle is not None else {}
    choice, cols, unclosed = _read(path, table, vehicle, where)
    notes = list(choice.notes)
    parts = {"imu": choice.imu, "odometry": choice.odometry, "steering": choice.steering}
    stamps_ns = {topic: _stamps(cols[topic], topic, table.get("stamps", "header") == "header", notes, where)
                 for topic in parts.values()}
    late = _transport_delays(cols, parts) if table.get("stamps", "header") != "header" else None
    # seconds from the first stamp: epoch nanoseconds as float64 would keep only ~0.2 us
    origin = min(int(t[0]) for t in stamps_ns.values())
    times = {topic: (t - origin) * 1e-9 for topic, t in stamps_ns.items()}
    imu_line = _imu_line(times[choice.imu])
    imu_rate = 1.0 / imu_line[1]
    rate = float(table.get("rate_hz") or 0.0) or imu_rate
    grid = _grid(times, imu_line, rate, where)
    warnings = [unclosed] if unclosed else []
    if late:
        warnings.append(late)
    from stid.ros.topic_files import names_files

    if table.get("fields") and not names_files(table):
        warnings.append("the vehicle file's [ros.fields] maps the columns of one CSV per topic; this is a bag, whose "
                        "messages' fields are read as they are: not used (an AckermannDrive angle's unit or sign: "
                        "[ros] steering_scale)")
    if rate < 0.95 * imu_rate:  # (a user's rate_hz = 20 for a 200 Hz IMU was taken without a word)
        warnings.append(f"[ros] rate_hz = {rate:g} is below the IMU's {imu_rate:.0f} Hz: the IMU is read at "
                        f"{rate:g} Hz without a filter against aliasing, so what it measured above {rate / 2:g} Hz "
                        "(noise, the motor's vibration) folds into the run; leave rate_hz out to use the IMU's own "
                        "rate")
    fine = int(round(FINE_FS / rate)) if rate < FINE_BELOW_HZ else 1
    phases = _step_phases(times[choice.steering], cols[choice.steering], choice, imu_line, rate)
    locked = _in_phase(phases)
    if locked is not None and fine * rate < 0.9 * LOCKED_FS:
        fine = int(round(LOCKED_FS / rate))
        notes.append(f"the steering command's steps fall at one point of the IMU's {rate:.0f} Hz period, or at a few "
                     f"({100 * locked:.0f}% of them in {FEW_PHASES} of {PHASE_BINS} parts of it: one clock for both, as "
                     "in a simulator), so on the IMU's grid each would be read early or late by its point's part of a "
                     "period")
    on_samples = float(np.mean(np.minimum(phases, 1.0 - phases) < ON_SAMPLE_S * rate)) if phases is not None else 0.0
    if on_samples >= ON_SAMPLES_SAID:
        warnings.append(f"{100 * on_samples:.0f}% of the steering command's steps are stamped at an IMU sample's "
                        "instant (one clock for both, as in a simulator): whether that sample saw the step the stamps "
                        "cannot tell, and the models take half of it there (an exact single-track bag with one step "
                        "in five so read Cf +1.1%, its interval missing the truth); stamp the command when it acts")
    sig, tilt = _signals(grid, times, cols, choice, rate, table, vehicle, where, notes, warnings, fine)
    sensors = {t: times[t] for t in (choice.imu, choice.odometry)}
    valid = _measured(grid, sensors)
    if imu_line[2] and rate == imu_rate:  # a clocked IMU's lost samples: no message holds their place
        lost = _lost_samples(grid, times[choice.imu], imu_line[1])
        valid &= ~lost
        if lost.any():
            n = int(lost.sum())
            notes.append(f"{choice.imu}: {n} of its samples lost ({100 * n / len(grid):.1f}% of the run's; silences "
                         f"over {SENSOR_CUT_S:g} s not counted: they cut the run): their places are left out of the fit")
    notes.insert(0, _grid_note(parts, times, rate, grid, choice, imu_rate))
    st_t, imu_t = times[choice.steering], times[choice.imu]
    quiet = np.flatnonzero(np.diff(st_t) > SENSOR_CUT_S)
    # (a silence of every topic, a pause in the recording, cuts the run: not the command's to hold)
    quiet = [k for k in quiet if np.sum((imu_t > st_t[k]) & (imu_t < st_t[k + 1])) * imu_line[1]
             > 0.5 * (st_t[k + 1] - st_t[k])]
    if quiet:
        notes.append(f"{choice.steering} was silent {len(quiet)} time(s) while the car's sensors went on, up to "
                     f"{max(st_t[k + 1] - st_t[k] for k in quiet):.1f} s: the servo holds its last command, so the "
                     "command is held there too")
    runs = []
    for k, (a, b) in enumerate(_pieces(grid, sensors)):
        if b - a < MIN_SAMPLES:
            continue
        cut = {key: v[a:b] for key, v in sig.items()}
        meta = {"source": where, "format": "ros", "fs": rate, "notes": list(notes) if not runs else [],
                "sensor_chain": sensor_chain.from_vehicle(vehicle, sensor_chain.ROS_NONE), "topics": dict(parts),
                # the stamp [ns] of the run's t = 0, to line it up with other data
                "stamp0_ns": origin + int(round(grid[a] * 1e9)),
                "imu_tilt": tilt}  # mount_roll, mount_pitch [rad] from the stand-still (stid calibrate)
        runs.append(Run(name=path.name if k == 0 else f"{path.name}#{k + 1}", t=grid[a:b] - grid[a],
                        steer=cut["steer"], ay=cut["ay"], r=cut["r"], vx=cut["vx"], ax=cut["ax"], meta=meta,
                        valid=None if valid[a:b].all() else valid[a:b], fine=fine,
                        steer_fine=fine_piece(sig.get("steer_fine"), fine, a, b, len(grid))))
    if not runs:
        raise InputError(f"{where}: no stretch of at least {MIN_SAMPLES} samples without a gap over "
                         f"{SENSOR_CUT_S:g} s in the IMU or the odometry")
    for run in runs:
        for w in warnings:
            run.warn(w)
        _gyro_zero(run)
    _share_gyro_zero(runs)
    for run in runs:
        _check(run, table, where)
    return runs


def _read(path, table, vehicle, where):
    """The topic of each part, the fields of those topics, and what was said of a bag read
    without its end ("" for the rest)."""
    servo_map = vehicle is not None and "gain" in vehicle.raw.get("steering", {})
    said = []
    with _open(path, table, where, said) as bag:
        choice = topic_map.choose(bag.topics, table, servo_map, where, bag.listing())
        wanted = {}
        for part, topic in (("imu", choice.imu), ("odometry", choice.odometry), ("steering", choice.steering)):
            if not bag.topics[topic].count:
                raise InputError(f"{where}: the {topic_map.ROLE_WORDS[part]} topic {topic} holds no messages")
            wanted.setdefault(topic, FIELDS[bag.topics[topic].msgtype])
        cols = bag.read(wanted)
    for topic, fields in wanted.items():
        bad = np.zeros(len(cols[topic]["t_log"]), bool)
        for f in fields:
            bad |= ~np.isfinite(cols[topic][f])
        if not bad.any():
            continue
        f = next(f for f in fields if not np.all(np.isfinite(cols[topic][f])))
        words = (f"{topic} has {int(bad.sum())} message(s) whose {f} is not a number (NaN or inf; the first is "
                 f"message {int(np.flatnonzero(bad)[0]) + 1} of {len(bad)}): a driver that failed to read its sensor")
        if bad.mean() > MAX_BAD_SHARE:
            raise InputError(f"{where}: {words}, in most of its messages: check the driver, or name another topic")
        # (such a message carries no measurement: it is taken as lost, as one the link lost)
        cols[topic] = {k: v[~bad] for k, v in cols[topic].items()}
        choice.notes.append(f"{words}: dropped, as lost messages")
    return choice, cols, "".join(said)


REGULAR_SHARE = 0.9  # of the IMU's intervals within a quarter period of a whole number of periods: a clocked sampler


def _imu_line(imu_t: np.ndarray) -> tuple:
    """``(t0, period, lost)`` of the IMU's sampling [s] and how many of its samples are missing
    (0 where it keeps no clock). A clocked IMU whose stamps jitter: the line
    through its stamps against their sample count (a lost message counted by its interval's
    length). Its median interval is not its period: a trial user's 30 Hz IMU with 0.5 ms of stamp
    jitter had a median 8 us short, and a grid at that rate drifted half a period off the samples
    over a minute; its values, interpolated between samples there, lost 5% at 3 Hz and read as a
    2 ms timing error. An IMU without a clock of its own (messages 14 to 48 ms apart, as a real
    F1/10 car's VESC IMU logged them): its first stamp and median interval."""
    d = np.diff(imu_t)
    med = float(np.median(d)) if len(d) else 0.0
    if len(d) < 2 or not med > 0:
        return float(imu_t[0]), med, 0
    periods = d / med
    if np.mean(np.abs(periods - np.round(periods)) < 0.25) < REGULAR_SHARE:
        return float(imu_t[0]), med, 0
    k = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(periods), 1.0))])
    period, t0 = np.polyfit(k, imu_t, 1)
    return float(t0), float(period) if period > 0 else med, int(k[-1]) + 1 - len(imu_t)


def _lost_samples(grid, imu_t, period) -> np.ndarray:
    """True at the grid instants of a clocked IMU's lost samples: inside an interval between two of
    its messages that holds most of a period beyond one (1.75 periods: a jittered pair 1.5 apart
    is no loss; a receive-timed IMU's jitter moves messages, it loses none), farther than half a
    period from both, in a silence short of SENSOR_CUT_S (a longer one cuts the run, and is said
    as such)."""
    d = np.diff(imu_t)
    gaps = np.flatnonzero((d >= 1.75 * period) & (d <= SENSOR_CUT_S))
    lost = np.zeros(len(grid), bool)
    for k in gaps:
        lost |= (grid > imu_t[k] + 0.5 * period) & (grid < imu_t[k + 1] - 0.5 * period)
    return lost


def _grid(times, imu_line, rate, where) -> np.ndarray:
    """Uniform instants over the time every topic covers, on the IMU's own instants (the line
    through its stamps: _imu_line) where the rate is the IMU's (its samples then reach the grid as
    they are, up to their stamps' jitter)."""
    t0 = max(t[0] for t in times.values())
    t1 = min(t[-1] for t in times.values())
    if t1 - t0 < MIN_SAMPLES / rate:
        spans = ", ".join(f"{topic} {t[0]:.2f}-{t[-1]:.2f} s" for topic, t in times.items())
        starts = sorted(t[0] for t in times.values())
        other_clock = starts[-1] - starts[0] > 86400.0  # a day apart: a driver stamps by its own clock (its boot)
        raise InputError(f"{where}: the topics do not overlap in time ({spans}, from the bag's first stamp): a run "
                         "needs the IMU, the odometry and the steering command at once"
                         + ("; their stamps are days apart, as when a driver stamps by its own clock (time since its "
                            "boot): [ros] stamps = \"receive\" times every topic by the bag's receive times"
                            if other_clock else ""))
    line0, period, _ = imu_line
    t0 = line0 + np.ceil((t0 - line0) / period - 1e-6) * period  # the first IMU instant in the overlap
    return t0 + np.arange(int(np.floor((t1 - t0) * rate + 1e-9)) + 1) / rate


def _signals(grid, times, cols, choice, rate, table, vehicle, where, notes, warnings, fine=1):
    """ax, ay, r (IMU), vx (odometry) interpolated onto the grid; steer held (and, ``fine`` > 1,
    ``steer_fine`` on a grid that many times as fine: Run.steer_fine). And the IMU's tilt at rest
    (``_tilt``)."""
    imu, imu_t = cols[choice.imu], times[choice.imu]
    acc = np.vstack([imu["linear_acceleration." + a] for a in "xyz"])
    gyro = np.vstack([imu["angular_velocity." + a] for a in "xyz"])
    acc, gyro = _body_axes(acc, gyro, table, vehicle, where, notes)
    sig = {"ax": np.interp(grid, imu_t, acc[0]), "ay": np.interp(grid, imu_t, acc[1]),
           "r": np.interp(grid, imu_t, gyro[2])}
    od, od_t = cols[choice.odometry], times[choice.odometry]
    speed_scale = float(table.get("speed_scale", 1.0))
    sig["vx"] = np.interp(grid, od_t, speed_scale * _forward_speed(od, warnings, choice.odometry))
    if speed_scale != 1.0:
        notes.append(f"{choice.odometry}: speed x {speed_scale:g} ([ros] speed_scale)")
    tilt = _tilt(np.vstack([np.interp(grid, imu_t, a) for a in acc]), sig["vx"], rate, vehicle, notes)
    _odometry_yaw(od, od_t, imu_t, gyro[2], choice, notes)
    st_t = times[choice.steering]
    command = cols[choice.steering]["drive.steering_angle" if choice.steering_type == ACKERMANN else "data"]
    scale = float(table.get("steering_scale", 1.0))
    if choice.steering_type == ACKERMANN:
        if scale != 1.0:  # a publisher's degrees, or its sign the other way (positive right)
            command = scale * command
            notes.append(f"{choice.steering}: steering_angle x {scale:g} ([ros] steering_scale)")
        if vehicle is not None and {"offset", "gain"} & set(vehicle.raw.get("steering", {})):
            warnings.append(f"the vehicle file's [steering] offset and gain map a servo command; {choice.steering} is "
                            "an AckermannDrive angle in rad, so they are not used (its unit or sign: [ros] "
                            "steering_scale, e.g. 0.0174533 for degrees, -1 for positive right)")
    elif "steering_scale" in table:
        raise InputError(f"{where}: [ros] steering_scale is for an AckermannDrive angle; {choice.steering} is a servo "
                         "command, which the vehicle file's [steering] offset and gain map (docs/ros.md)")
    # the servo holds each command until the next: the staircase's mean over each sample period, which
    # the models' input (lines between samples) puts at its own time (stid.held_command)
    sig["steer"] = interval_means(st_t, command, grid, 1.0 / rate)
    fine_grid = grid[0] + np.arange((len(grid) - 1) * fine + 1) / (fine * rate) if fine > 1 else None
    command_fine = None if fine_grid is None else interval_means(st_t, command, fine_grid, 1.0 / (fine * rate))
    peak = float(np.max(np.abs(sig["steer"]))) if len(sig["steer"]) else 0.0
    from stid.steer_units import NOT_RADIANS, not_radians

    if choice.steering_type == ACKERMANN and peak > NOT_RADIANS:  # (a new user's bag in degrees: fitted to -88% ay)
        raise InputError(not_radians(where, choice.steering, peak) + " AckermannDrive's steering_angle is in rad "
                         "(REP 103): have its publisher send rad, or read this bag's in degrees with [ros] "
                         "steering_scale = 0.0174533 in the vehicle file")
    if choice.steering_type == FLOAT64:
        from stid.steer_units import road_wheel_angle

        raw = sig["steer"]
        sig["steer"], said, warned = road_wheel_angle(raw, sig["r"], sig["vx"], sig["ay"], rate, vehicle,
                                                      where, choice.steering)
        notes += said
        warnings += warned
        if command_fine is not None:
            command_fine = _same_map(raw, sig["steer"], command_fine)
    if command_fine is not None:
        sig["steer_fine"] = command_fine
        notes.append(f"the steering command drives the models at {fine * rate:.0f} Hz, {fine} steps per IMU "
                     f"sample: at the IMU's {rate:.0f} Hz its steps would spread over a sample period")
    return sig, tilt


def _step_phases(st_t, command_cols, choice, imu_line, rate) -> np.ndarray | None:
    """Where in the grid's period (0-1) each of the command's steps falls (the grid: the IMU's
    instants, imu_line's start and period), or None with too few steps to tell."""
    command = command_cols["drive.steering_angle" if choice.steering_type == ACKERMANN else "data"]
    steps = np.flatnonzero(np.diff(command) != 0) + 1
    if len(steps) < 20:
        return None
    return (st_t[steps] - imu_line[0]) * rate % 1.0


def _in_phase(phases) -> float | None:
    """The share of the steps in the FEW_PHASES fullest of PHASE_BINS parts of the period, when it is
    LOCKED_SHARE or more (else None)."""
    if phases is None:
        return None
    counts = np.sort(np.histogram(phases, bins=PHASE_BINS, range=(0.0, 1.0))[0])[::-1]
    share = float(counts[:FEW_PHASES].sum() / len(phases))
    return share if share >= LOCKED_SHARE else None


ON_SAMPLES_SAID = 0.05  # of the steps stamped at a sample's instant: said (a clock of its own puts ~0% there)
ON_SAMPLE_S = 1e-6


def _same_map(raw: np.ndarray, mapped: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x`` through the affine map (a servo command to the road-wheel angle: stid.steer_units)
    that took ``raw`` to ``mapped``."""
    i, j = int(np.argmin(raw)), int(np.argmax(raw))
    if raw[j] == raw[i]:
        return np.full(len(x), float(mapped[i]) if len(mapped) else 0.0)
    gain = (mapped[j] - mapped[i]) / (raw[j] - raw[i])
    return mapped[i] + gain * (x - raw[i])


def _check(run, table, where) -> None:
    """Units and signs against kinematics (stid.input_checks); an IMU turned 90 deg named."""
    try:
        input_checks.check_kinematics(run, source="ros")
    except InputError as e:
        _check_turned(run, table, where)  # a better message, when that is what is wrong
        if "(ay ~ -vx*r)" in str(e):  # (input_checks._sign_message: ay and r of opposite signs)
            _check_half_turned(run, table, where)
        raise
    if any("could not be checked" in w for w in run.meta.get("warnings", [])):
        _check_turned(run, table, where)


@contextlib.contextmanager
def _open(path, table, where, said):
    """A bag, or a directory of per-topic CSVs that the [ros] table names. A ROS 2 bag without its
    end (its recorder killed, or still recording) is read up to its last complete chunk, and
    that is said in ``said`` (a new user's killed recordings were refused, pointing to `mcap
    recover`, a tool they may not have, while `stid live` read the same files)."""
    from stid.ros import topic_files
    from stid.ros.unclosed import being_recorded, readable_copy

    if path.is_dir() and not (path / "metadata.yaml").exists() and topic_files.names_files(table):
        with topic_files.TopicFiles(path, table) as files:
            yield files
        return
    inside = split_files(path) if path.is_dir() else [path]
    bare = path.is_dir() and not (path / "metadata.yaml").exists()  # (rosbag2 writes it last)
    if bare and len(inside) > 1:
        # a split bag whose recorder was killed: its pieces in order, the last perhaps not closed
        with tempfile.TemporaryDirectory(prefix="stid-unclosed-") as scratch:
            pieces = _closed_pieces(inside, Path(scratch), said)
            with Bag(path, pieces=pieces) as bag:
                yield bag
        return
    cut = being_recorded(inside[0]) if len(inside) == 1 and not messages_compressed(inside[0].parent) else None
    if cut is None:
        # (a bag directory without its metadata.yaml: its one file)
        with Bag(inside[0] if bare and len(inside) == 1 else path) as bag:
            yield bag
        return
    with tempfile.TemporaryDirectory(prefix="stid-unclosed-") as scratch:
        copy = Path(scratch) / cut.name
        n = readable_copy(cut, copy)
        if not n:
            raise InputError(f"{where}: the bag was not closed (its recorder was stopped, or is still recording) and "
                             "holds no complete chunk of messages yet")
        said.append(f"the bag was not closed (its recorder was killed, or is still recording): read up to its last "
                    f"complete chunk, {n} messages of {cut.stat().st_size / 1e6:.1f} MB; `mcap recover` may save "
                    "a little more of its end")
        with Bag(copy) as bag:
            yield bag


def _closed_pieces(inside: list, scratch: Path, said: list) -> tuple:
    """The pieces of a split bag read without its metadata.yaml, each not closed (its recorder
    killed while writing it: the last, as a rule) replaced by a copy up to its last complete
    chunk in ``scratch``; what was done is said in ``said``. Returns the pieces to read."""
    from stid.ros.unclosed import being_recorded, readable_copy

    pieces, copied = [], []
    for f in inside:
        cut = being_recorded(f) if not messages_compressed(f.parent) else None
        if cut is None:
            pieces.append(f)
            continue
        copy = scratch / cut.name
        if readable_copy(cut, copy):
            pieces.append(copy)
        copied.append(f.name)
    said.append(f"the bag's directory has no metadata.yaml (its recorder was killed, or is still recording): its "
                f"{len(inside)} pieces read in order ({', '.join(f.name for f in inside)})"
                + (f"; {', '.join(copied)} not closed: read up to its last complete chunk" if copied else ""))
    if not pieces:
        raise InputError(f"{inside[0].parent}: none of the bag's pieces holds a complete chunk of messages yet")
    return pieces


TRANSPORT_SAID_MS = 1.0  # receive delays this far apart between the IMU and the command are said


def _transport_delays(cols, parts) -> str | None:
    """Timed by receive: a warning when the IMU's messages reach the bag later after their header
    stamps than the command's do. Against the command the outputs are then late by transport alone,
    and a fit reads that as the car's: a trial user's bag, its IMU 30 ms in transit and its command
    2 ms, named a 58 ms sensor_delay and an accelerometer 4.7 cm behind the CG that were not there."""
    def delay_ms(topic):
        col = cols[topic]
        if "header.stamp.sec" not in col:
            return None
        head = col["header.stamp.sec"].astype(np.int64) * 1_000_000_000 + col["header.stamp.nanosec"].astype(np.int64)
        return None if np.all(head == 0) else float(np.median(col["t_log"].astype(np.int64) - head)) * 1e-6

    imu, steering = delay_ms(parts["imu"]), delay_ms(parts["steering"])
    if imu is None or steering is None or abs(imu - steering) < TRANSPORT_SAID_MS:
        return None
    return (f"timed by receive ([ros] stamps = \"receive\"), yet the messages carry header stamps: "
            f"{parts['imu']} reaches the bag {imu:.1f} ms after its stamps and {parts['steering']} {steering:.1f} ms, "
            f"so the outputs lag the command by {imu - steering:+.1f} ms of transport that is not the car's (a fit "
            "reads it as a servo lag or a sensor delay); where the header stamps hold, time by them (leave "
            "stamps out)")


def _stamps(col, topic, use_header, notes, where) -> np.ndarray:
    """Nanoseconds (from the epoch or the bag's clock) of each message, increasing."""
    log = col["t_log"].astype(np.int64)
    if "header.stamp.sec" in col and use_header:
        t = col["header.stamp.sec"].astype(np.int64) * 1_000_000_000 + col["header.stamp.nanosec"].astype(np.int64)
        if np.all(t == 0):
            notes.append(f"{topic}: header stamps are all zero: timed by the bag's receive times")
            t = log
    else:
        t = log
        if "header.stamp.sec" not in col:
            notes.append(f"{topic} has no header: timed by the bag's receive times")
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if len(back):
        k = int(back[0])
        kind = "header stamps" if t is not log else "receive times"
        raise InputError(f"{where}: {topic}'s {kind} go backwards at message {k + 2} of {len(t)} (by "
                         f"{-dt[k] * 1e-6:.1f} ms, {(t[k + 1] - t[0]) * 1e-9:.2f} s in): two publishers on one topic, or a "
                         "clock reset; record that topic from one source"
                         + (", or time by receive: [ros] stamps = \"receive\" (each topic is then late by its own "
                            "transport, which stid says where it differs)" if kind == "header stamps" else ""))
    same = dt == 0
    if same.any():
        keep = np.concatenate([[True], ~same])
        for k in col:
            col[k] = col[k][keep]
        t = t[keep]
        notes.append(f"{topic}: {int(same.sum())} messages repeat the stamp before them: dropped")
    return t


def _body_axes(acc, gyro, table, vehicle, where, notes):
    """IMU axes -> the car's (ISO 8855), in m/s^2 and rad/s; gravity found and said."""
    if table.get("accel_unit") == "g":
        acc = acc * G
    if table.get("gyro_unit") == "deg/s":
        gyro = np.radians(gyro)
    m = topic_map.axes_matrix(table["imu_axes"], where) if "imu_axes" in table else np.eye(3)
    acc, gyro = m @ acc, m @ gyro
    mean = np.median(acc, axis=1)
    norm = float(np.linalg.norm(mean))
    if abs(norm - 1.0) < 0.15 and table.get("accel_unit") != "g":
        raise InputError(f"{where}: the IMU's accelerometer reads {norm:.2f} at rest-level: that is gravity in g, "
                         "not m/s^2 (REP 145 wants m/s^2; the VESC driver's sensors/imu/raw sends g): add "
                         "accel_unit = \"g\" to the vehicle file's [ros]"
                         + (", and gyro_unit = \"deg/s\" (that driver's gyro unit; stid checks it against the "
                            "kinematics once the accelerometer reads)" if table.get("gyro_unit") != "deg/s" else ""))
    if abs(norm - G) < 0.2 * G:
        axis = int(np.argmax(np.abs(mean)))
        if axis != 2 or mean[2] < 0:
            seen = f"{'-' if mean[axis] < 0 else '+'}{'xyz'[axis]}"
            rows = list(table.get("imu_axes", ["x", "y", "z"]))
            fixed = ", ".join(f'"{a}"' for a in _gravity_up(rows, seen))
            raise InputError(f"{where}: gravity is on the car's {seen} axis after [ros] imu_axes {rows}: it must be on "
                             f"+z (z up); the IMU's mounting is declared wrong: imu_axes = [{fixed}] puts it up (if x "
                             "is then not forward, stid says how to turn it about z; docs/ros.md)")
        roll = float(vehicle.sensors.get("mount_roll", 0.0)) if vehicle is not None else 0.0
        pitch = float(vehicle.sensors.get("mount_pitch", 0.0)) if vehicle is not None else 0.0
        if roll or pitch:
            acc = convert.mount_rotation(roll, pitch) @ acc
            notes.append(f"IMU tilt undone: roll {np.degrees(roll):+.2f} deg, pitch {np.degrees(pitch):+.2f} deg "
                         "(the vehicle file's [sensors])")
        # (its tilt is taken at rest, by _tilt: over the run, a steady turn's ay read as a tilt of 5 deg)
        notes.append(f"the accelerometer holds gravity (on +z, {norm:.2f} m/s^2 the run's median): ay is the "
                     "specific force the car's y axis feels")
    elif norm < 0.2 * G:
        notes.append("the accelerometer has gravity removed (driver-side): ay taken as it is")
    else:
        raise InputError(f"{where}: the IMU's accelerometer reads {norm:.2f} m/s^2 on average: neither gravity "
                         "(9.81) nor gravity removed (0); check [ros] accel_unit")
    return acc, gyro


def _gravity_up(rows: list, seen: str) -> list:
    """The imu_axes that turn ``rows`` (the declared ones) so that gravity, now on the car's
    ``seen`` axis, is on +z: the one quarter or half turn about x or y that does it (right-handed)."""
    def flip(a):
        return a[1:] if a.startswith("-") else "-" + a

    x, y, z = rows
    return {"-z": [x, flip(y), flip(z)],  # upside down: half a turn about x
            "+x": [flip(z), y, x], "-x": [z, y, flip(x)],  # a quarter turn about y
            "+y": [x, flip(z), y], "-y": [x, z, flip(y)]}[seen]  # a quarter turn about x


def _check_half_turned(run, table, where) -> None:
    """ay against -vx*r: one of ay and r has its sign the other way, so the IMU is turned half a turn
    from the axes declared, about z (x and y the other way: ay flipped, r not) or about y (x and z:
    r flipped). r against the steer tells which. Said with the imu_axes that fix it (a trial user
    with an IMU turned about y was told to fix imu_axes, not how)."""
    est = input_checks._kinematic_gains(run)
    if isinstance(est, str) or est[0] >= 0:
        return
    _, steer_sign = est

    def flip(a):
        return a[1:] if a.startswith("-") else "-" + a

    x, y, z = list(table.get("imu_axes", ["x", "y", "z"]))
    if steer_sign >= 0:  # r turns with the steer: ay is the flipped one (or, at 0, gravity on +z says z is right)
        fixed, how = [flip(x), flip(y), z], "half a turn about z (its x points backwards)"
    else:
        fixed, how = [flip(x), y, flip(z)], "half a turn about y (upside down, its x backwards)"
    axes = ", ".join(f'"{a}"' for a in fixed)
    raise InputError(f"{where}: the yaw rate and the lateral acceleration have opposite signs (ay ~ -vx*r): the IMU "
                     f"is turned {how} from the axes {'declared' if 'imu_axes' in table else 'assumed'}; set in the "
                     f"vehicle file's [ros]: imu_axes = [{axes}]")


def _check_turned(run, table, where) -> None:
    """An IMU turned 90 deg about z and not declared so: the car's lateral acceleration is on
    its x axis (ay = vx*r holds for ax instead). Said with the imu_axes that fix it."""
    lo, hi = input_checks.CONSISTENT_GAIN

    def gain(channel):
        g = input_checks.ay_gain(Run("", run.t, run.steer, getattr(run, channel), run.r, run.vx))
        return None if isinstance(g, str) else g

    g_y = gain("ay")
    if g_y is not None and lo <= g_y <= hi:
        return
    g_x = gain("ax")
    if g_x is None or not lo <= abs(g_x) <= hi:
        return
    s = 1 if g_x > 0 else -1
    rows = table.get("imu_axes", ["x", "y", "z"])
    flip = lambda a: a[1:] if a.startswith("-") else "-" + a  # noqa: E731
    fixed = [rows[1] if s < 0 else flip(rows[1]), rows[0] if s > 0 else flip(rows[0]), rows[2]]
    axes = ", ".join(f'"{a}"' for a in fixed)
    declared = "declared" if "imu_axes" in table else "assumed (none declared)"
    raise InputError(f"{where}: ax follows vx*r (ax = {g_x:.2f} x vx*r) and ay does not: the IMU is turned 90 deg "
                     f"about z from the axes {declared}; set in the vehicle file's [ros]: imu_axes = [{axes}]")


TILT_NOTE_DEG = 1.0  # g sin(1 deg) = 0.17 m/s^2 on ay: worth a line in the vehicle file


def _tilt(acc, vx, rate, vehicle, notes):
    """The IMU's tilt from gravity while the car stands still, ``{"mount_roll", "mount_pitch"}``
    [rad] as ``stid calibrate`` writes them (None without a stand-still or gravity). Said with
    the [sensors] lines that undo it when none are declared."""
    from stid import segments

    still = segments.still_mask(vx, rate)
    if still.sum() < 0.5 * rate:
        return None
    g = acc[:, still].mean(axis=1)
    if abs(np.linalg.norm(g) - G) > 0.2 * G:
        return None  # gravity removed (or not only gravity): nothing to tell the tilt by
    roll, pitch = convert.mounting_from_gravity(g)
    found = {"mount_roll": roll, "mount_pitch": pitch}
    sensors = vehicle.sensors if vehicle is not None else {}
    tilt = np.degrees(np.arctan2(np.hypot(g[0], g[1]), g[2]))
    if "mount_roll" in sensors or "mount_pitch" in sensors or tilt < TILT_NOTE_DEG:
        return found
    notes.append(f"the IMU sits tilted {tilt:.1f} deg at rest (ay {g[1]:+.2f}, ax {g[0]:+.2f} m/s^2 of gravity); "
                 f"to undo it, add to the vehicle file's [sensors]: mount_roll = {roll:.4f} and mount_pitch = "
                 f"{pitch:.4f} (rad), or run 'stid calibrate' on it")
    return found


def _forward_speed(od, warnings, topic) -> np.ndarray:
    """The forward speed: the twist's linear.x (REP 105: in the car's frame). A twist with a large
    sideways part is in another frame, most often the world's (child_frame_id the same as the
    header's "odom"): there linear.x is the speed along the world's x, whose sign says where the car
    heads, not whether it reverses (it was taken as the sign: a fresh user's car heading west for
    65% of a run read as reversing, and that 65% was left out as such). The speed is then the
    twist's magnitude, forward, and a warning says so."""
    vx = od["twist.twist.linear.x"]
    vy = od["twist.twist.linear.y"]
    if np.sqrt(np.mean(vy ** 2)) > 0.3 * max(np.sqrt(np.mean(vx ** 2)), 1e-9):
        warnings.append(f"{topic}: the twist has a large sideways part (rms {np.sqrt(np.mean(vy ** 2)):.2f} m/s "
                        f"against {np.sqrt(np.mean(vx ** 2)):.2f} along x): it is not in the car's frame (REP 105 "
                        "puts it in the child frame; is child_frame_id the world's, as 'odom'?). vx is taken as its "
                        "magnitude, forward: reversing cannot be told from it (publish the twist in the car's "
                        "frame, e.g. base_link, to have it)")
        return np.hypot(vx, vy)
    return vx


def _odometry_yaw(od, od_t, imu_t, imu_r, choice, notes) -> None:
    """The odometry's yaw rate is not used (the VESC's is computed from the steering command,
    not measured); an opposite sign is said, since it flips every comparison made with it."""
    w = od["twist.twist.angular.z"]
    if not np.any(w):
        return
    r = np.interp(od_t, imu_t, imu_r)
    if np.std(r) > 0 and np.std(w) > 0 and np.corrcoef(r, w)[0, 1] < -0.5:
        notes.append(f"{choice.odometry}'s yaw rate has the opposite sign to the IMU's (not used: r is the gyro's)")


def _measured(grid, times) -> np.ndarray:
    """False at grid points inside a gap of some sensor topic (lost messages): held, not measured."""
    ok = np.ones(len(grid), bool)
    for t in times.values():
        dt = np.diff(t)
        med = float(np.median(dt))
        for k in np.flatnonzero(dt > GAP_PERIODS * med):
            ok[(grid > t[k] + med) & (grid < t[k + 1] - med)] = False
    return ok


def _pieces(grid, times):
    """The stretches between sensor silences longer than SENSOR_CUT_S (grid index ranges)."""
    gaps = sorted((t[k], t[k + 1]) for t in times.values() for k in np.flatnonzero(np.diff(t) > SENSOR_CUT_S))
    pieces, a = [], 0
    for lo, hi in gaps:
        b = int(np.searchsorted(grid, lo, side="right"))
        if b > a:
            pieces.append((a, b))
        a = max(a, int(np.searchsorted(grid, hi, side="left")))
    if a < len(grid):
        pieces.append((a, len(grid)))
    return pieces


def _grid_note(parts, times, rate, grid, choice, imu_rate) -> str:
    # messages per second over the topic's span (a planner's bursts: its median interval read 91 Hz for
    # 43.5 Hz); the IMU's clock (_imu_line)
    rates = {t: (len(tt) - 1) / max(float(tt[-1] - tt[0]), 1e-9) for t, tt in times.items()}
    rates[parts["imu"]] = imu_rate
    last = max(t[-1] for t in times.values())
    return (f"resampled to a uniform {rate:.1f} Hz grid: ay, ax, r from {parts['imu']} ({rates[parts['imu']]:.0f} Hz) "
            f"and vx from {parts['odometry']} ({rates[parts['odometry']]:.0f} Hz) interpolated linearly, steer from "
            f"{parts['steering']} ({rates[parts['steering']]:.0f} Hz, {choice.steering_type.split('/')[-1]}) held (a "
            f"command holds until the next); {grid[-1] - grid[0]:.1f} s where all three overlap ({grid[0]:.2f} s at "
            f"the start and {last - grid[-1]:.2f} s at the end left out)")


def _gyro_zero(run) -> None:
    # the odometry's speed comes from the motor (ERPM): no hall pulses to wait for
    convert.zero_from_stand_still(run, lookback_s=0.0)
    bias = run.meta["gyro_bias"]
    if bias is None:
        return
    run.r = run.r - bias
    run.meta.setdefault("notes", []).append(f"gyro zero {bias:+.4f} rad/s, from the stand-still, taken off r")


def _share_gyro_zero(runs) -> None:
    """A piece cut off by a silence (an IMU driver that stalled, a clock that jumped) has no
    stand-still of its own; the zero from the nearest piece of the same bag that has one holds
    for it (one IMU, one recording; stid.load does the same for the pieces of a logged run).
    Left as the IMU gives it, a gyro bias of 0.02 rad/s stayed in the second piece."""
    donors = [d for d in runs if d.meta.get("gyro_bias") is not None]
    for run in runs:
        if run.meta.get("gyro_bias") is not None:
            continue
        if not donors:
            run.warn("the run never stands still: the gyro's zero is taken as the IMU gives it (start runs with ~2 s "
                     "standing still)")
            continue
        start = run.meta["stamp0_ns"]
        donor = min(donors, key=lambda d: abs(d.meta["stamp0_ns"] - start))
        bias = donor.meta["gyro_bias"]
        run.r = run.r - bias
        convert.set_gyro_zero(run, donor.meta["gyro_zero"], f"the stand-still of {donor.name} (same bag)")
        away = abs(donor.meta["stamp0_ns"] - start) * 1e-9
        run.meta.setdefault("notes", []).append(f"gyro zero {bias:+.4f} rad/s, from the stand-still of {donor.name} "
                                                f"({away:.0f} s apart in this bag), taken off r")
