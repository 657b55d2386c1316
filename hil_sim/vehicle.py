"""Truth dynamics of the simulated car: a nonlinear single-track vehicle.

States: position X, Y and heading psi (world), body velocities vx, vy and yaw rate
r, the front road-wheel angle delta, the axle side forces Fyf, Fyr (when tyres
relax), the roll angle phi and its rate, and the distance travelled s (for the
hall sensor). ISO 8855 axes: x forward, y left, z up; left turns positive.

Effects are switched on one by one (``Effects``); with all of them off the truth
is the linear single-track model with a speed controller, so an identifier that
fits that model should recover Cf, Cr and Iz exactly up to noise. A user's own
truth-side effect (``hil_sim.effect_file``) adds its hooks through ``Effects.custom``.

The steering linkage and the locked differential are solved here as mechanisms (a
four-bar per wheel, the rear wheels' longitudinal slips), not as the identifier's
formulas, so the identifier is tested against physics and not against itself.

This module is the simulator's own physics. It must not import ``stid``: a hidden
effect is only a test if the identifier was written without this code.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

G = 9.81

EFFECT_NAMES = ("actuator_lag", "tyre_relaxation", "body_roll", "accel_offset",
                "tyre_saturation", "sensor_bias", "vibration", "steering_nonlinearity", "locked_diff",
                "sensor_delay", "steer_offset", "gyro_scale")


@dataclass
class CarParams:
    """The reference 1:8 car (mass and axle positions from the scaled-car study).

    Iz and the cornering stiffnesses are not in the study; they are chosen
    plausible for a 9.3 kg, 0.52 m wheelbase car: Iz = 0.25 kg m^2 (a box of the
    car's size, 0.55 x 0.30 m, with mass concentrated toward the centre), and a
    normalised cornering stiffness of ~8 /rad front and ~11.6 /rad rear (axle
    load 50.5 N front, 40.8 N rear): Cf = 400 N/rad, Cr = 475 N/rad per axle,
    which understeers slightly, as RC cars are set up to.
    """

    mass: float = 9.31  # kg
    a: float = 0.2326  # m, CG to front axle
    b: float = 0.2874  # m, CG to rear axle
    Iz: float = 0.25  # kg m^2
    Cf: float = 400.0  # N/rad, front axle
    Cr: float = 475.0  # N/rad, rear axle
    wheel_radius: float = 0.045  # m
    track: float = 0.25  # m, between left and right wheels
    Cx: float = 700.0  # N per unit longitudinal slip, rear (driven) axle; the fronts roll freely
    # effect magnitudes (used only when the effect is on)
    tau_steer: float = 0.06  # s, servo first-order lag
    steer_rate_max: float = 6.0  # rad/s at the road wheel (~0.1 s per 60 deg servo)
    sigma_f: float = 0.12  # m, front relaxation length
    sigma_r: float = 0.10  # m, rear relaxation length
    roll_gain: float = 3.0 * math.pi / 180 / G  # rad of roll per m/s^2 of ay (3 deg/g)
    roll_freq: float = 4.0  # Hz, undamped roll natural frequency
    roll_damping: float = 0.4  # -, roll damping ratio
    x_acc: float = 0.08  # m, accelerometer ahead of the CG
    mu: float = 0.9  # -, tyre-road friction (saturation)
    mf_shape: float = 1.3  # -, magic-formula shape factor C
    bias_r: float = 0.03  # rad/s gyro bias appearing after start-up (~1.7 deg/s)
    bias_ay: float = 0.25  # m/s^2 accelerometer y bias appearing after start-up
    bias_ramp_s: float = 4.0  # s, how fast the thermal bias drifts in after the still phase
    # steering linkage (steering_nonlinearity), top view: the servo horn's tip drives both tie
    # rods; each steering arm sits behind its kingpin, angled inward (Ackermann). A short horn
    # on long arms (a slow ratio: ~55 deg of servo for 18 deg at the wheels) makes the road-wheel
    # angle fall behind the command at large angles
    steer_horn: float = 0.006  # m, servo horn (servo saver) radius to the tie-rod ball
    steer_arm: float = 0.020  # m, steering arm length, kingpin to tie-rod ball
    steer_ackermann_deg: float = 15.0  # deg, steering arms' inward angle
    steer_servo_x: float = -0.03  # m, servo shaft behind the front axle
    kingpin_inset: float = 0.015  # m, kingpins inboard of the wheel centres
    sensor_delay_s: float = 0.02  # s, accelerometer and gyro reach the ADC late (sensor_delay)
    # steer_offset: the servo's centre pulse leaves the road wheels this far left of straight (a
    # horn off by part of a spline tooth, tie rods of unequal length); the review's real 1:10 car
    # needed -0.03 rad
    steer_trim: float = 0.025  # rad at the road wheels
    # gyro_scale: the gyro's true sensitivity over the datasheet's 3.3 mV/(deg/s) that the host
    # converts with, minus one (parts differ by several percent)
    gyro_sens_error: float = 0.05
    # steering servo pulse: centre and gain from road-wheel angle (500 us per 25 deg)
    steer_center_us: float = 1500.0
    steer_us_per_rad: float = 500.0 / math.radians(25.0)
    # the receiver's pulse train runs on its own clock: nominal 20 ms, its crystal off by
    # servo_clock_ppm, each edge jittered by servo_jitter_us rms, so the falling edges
    # sweep through the firmware's sample period instead of locking to it
    servo_period_us: int = 20000
    servo_phase_us: int = 3000
    servo_clock_ppm: float = 300.0
    servo_jitter_us: float = 2.0

    @property
    def L(self) -> float:
        return self.a + self.b

    def axle_loads(self):
        return self.mass * G * self.b / self.L, self.mass * G * self.a / self.L

    def as_dict(self):
        return asdict(self)



def board_opts(car: CarParams) -> dict:
    """The simulated board of ``car`` (hil_sim.firmware_runner's board_opts): a car of its own
    (``--car``) carries a board of its own, its machine.unique_id() from the car's values, so that
    a logger told "the same board only" refuses another car that comes up on its port (every
    simulated car had one uid, and a trial's run took in 11,600 samples of another car). The
    reference car keeps the board it always had; one car file is one board across its runs."""
    if car == CarParams():
        return {}
    import hashlib

    return {"uid": list(hashlib.sha256(repr(sorted(asdict(car).items())).encode()).digest()[:8])}

@dataclass
class Effects:
    on: set = field(default_factory=set)
    custom: tuple = ()  # truth-side effects of users (hil_sim.effect_file.TruthEffect)

    def __post_init__(self):
        unknown = set(self.on) - set(EFFECT_NAMES)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {', '.join(EFFECT_NAMES)}")

    def __contains__(self, name):
        return name in self.on


@dataclass
class Trajectory:
    """Truth signals on the simulation grid."""

    t: np.ndarray
    delta_cmd: np.ndarray  # rad, commanded road-wheel angle as the servo receives it
    delta: np.ndarray  # rad, actual road-wheel angle
    vx: np.ndarray
    vy: np.ndarray
    r: np.ndarray
    r_dot: np.ndarray
    ax: np.ndarray  # m/s^2 at the CG, body frame (dvx/dt - vy r)
    ay: np.ndarray  # m/s^2 at the CG, body frame (dvy/dt + vx r)
    phi: np.ndarray  # rad, roll angle (positive: right side down, as in a left turn)
    s: np.ndarray  # m, distance travelled by the rear wheels
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    steer_pulses_us: np.ndarray  # one servo pulse width per receiver pulse
    Fx: np.ndarray  # N, drive force at the rear axle
    states: np.ndarray | None = None  # (n, 13) raw states, for dense output
    rhs: object = None  # the right-hand side, for dense output
    steer_rise_us: np.ndarray | None = None  # rising edge of each pulse [us since t = 0]
    switches: dict | None = None  # commands taken inside a step: step, t, state, old, new
    dt_step: float | None = None  # the integration step (a window of rows keeps the whole run's t[1] - t[0])

    def dense(self, tg: np.ndarray) -> dict:
        """Outputs between integration steps. Within a step the servo command is held, so
        each output is interpolated between its value at the step's start and its value at
        the step's end under the same command (re-evaluated where the command changes
        there). Plain interpolation of the outputs would ramp every steer step in up to a
        step early, through ay's direct dependence on the steer."""
        n = len(self.t)
        left = {"ay": self.ay, "ax": self.ax, "r_dot": self.r_dot}
        right = {k: np.append(v[1:], v[-1]).copy() for k, v in left.items()}
        sw = self.switches or {"step": np.zeros(0, int)}
        inside = set(sw["step"].tolist())  # steps where the command changed at a falling edge within
        changed = np.flatnonzero(self.delta_cmd[1:] != self.delta_cmd[:-1])  # steps i -> i+1
        for i in changed:
            if i in inside:
                continue
            right_ax, right_ay, right_rd = self._outputs(self.states[i + 1], self.delta_cmd[i], self.v_ref[i])
            right["ax"][i], right["ay"][i], right["r_dot"][i] = right_ax, right_ay, right_rd
        idx = np.clip(np.searchsorted(self.t, tg, side="right") - 1, 0, n - 1)
        frac = np.clip((tg - self.t[idx]) / np.maximum(np.diff(self.t, append=self.t[-1] + 1)[idx], 1e-12), 0, 1)
        out = {k: left[k][idx] + (right[k][idx] - left[k][idx]) * frac for k in left}
        # a step with a falling edge inside: the old command up to the edge, the new one after
        names = ("ax", "ay", "r_dot")
        h = self.dt_step if self.dt_step is not None else self.t[1] - self.t[0]
        for j, i in enumerate(sw["step"].tolist()):
            lo, hi = np.searchsorted(tg, [self.t[i], self.t[i] + h], side="left")
            if hi <= lo:
                continue
            tf, xf = sw["t"][j], sw["state"][j]
            minus = self._outputs(xf, sw["old"][j], self.v_ref[i])
            plus = self._outputs(xf, sw["new"][j], self.v_ref[i])
            seg = tg[lo:hi]
            before = seg < tf
            fb = np.clip((seg - self.t[i]) / max(tf - self.t[i], 1e-12), 0, 1)
            t_end = self.t[i + 1] if i + 1 < n else self.t[i] + h
            fa = np.clip((seg - tf) / max(t_end - tf, 1e-12), 0, 1)
            for k, name in enumerate(names):
                a = left[name][i] + (minus[k] - left[name][i]) * fb
                b = plus[k] + (right[name][i] - plus[k]) * fa
                out[name][lo:hi] = np.where(before, a, b)
        for k, v in (("r", self.r), ("vx", self.vx), ("phi", self.phi)):
            out[k] = np.interp(tg, self.t, v)
        return out

    def _outputs(self, state, dcmd, vref):
        """(ax, ay, r_dot) at a state under a command."""
        x = list(state)
        _, aux = self.rhs(x, float(dcmd), float(vref))
        return aux[3] - x[4] * x[5], aux[4] + x[3] * x[5], aux[5]


def wheel_speeds(traj: "Trajectory", car: "CarParams"):
    """Angular speeds [rad/s] of fl, fr, rl, rr. Front wheels roll freely; the driven rear
    wheels slip by s = Fx / Cx (quasi-static: the wheel's spin-up is far faster than the car),
    or, with a locked differential, turn together at the speed that delivers Fx."""
    R, h = car.wheel_radius, car.track / 2
    s = traj.Fx / car.Cx
    out = []
    for side, slip in ((-1, 0.0), (1, 0.0), (-1, s), (1, s)):
        out.append(np.maximum(traj.vx + side * h * traj.r, 0.0) * (1 + slip) / R)
    if getattr(traj, "spool", False):
        vl = np.maximum(traj.vx - h * traj.r, 0.1)
        vr = np.maximum(traj.vx + h * traj.r, 0.1)
        w = (traj.Fx / (car.Cx / 2) + 2.0) / (1.0 / vl + 1.0 / vr) / R
        w = np.where(traj.vx > 0.3, w, out[2])
        out[2], out[3] = w, w.copy()
    return out


def servo_rise_times_us(car: "CarParams", duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Rising edges [us] of the receiver's pulse train over ``duration_s``: its own clock
    (nominal period off by ``servo_clock_ppm``) plus ``servo_jitter_us`` rms per edge."""
    period = car.servo_period_us * (1.0 + car.servo_clock_ppm * 1e-6)
    n = int((duration_s * 1e6 - car.servo_phase_us) // period) + 1
    t = car.servo_phase_us + np.arange(max(n, 1)) * period + car.servo_jitter_us * rng.standard_normal(max(n, 1))
    return np.round(np.maximum(t, 0)).astype(np.int64)


def _wheel_angle(servo: float, side: int, car: CarParams) -> float:
    """One front wheel's steer angle [rad] for the servo horn angle ``servo`` [rad]: the
    four-bar horn - tie rod - steering arm, solved exactly (circle intersection). side +1
    is the left wheel, -1 the right; the tie rod's length makes both wheels straight at
    servo angle 0."""
    w = car.track / 2 - car.kingpin_inset
    beta = math.radians(car.steer_ackermann_deg)
    ra, rs = car.steer_arm, car.steer_horn
    ux, uy = -math.cos(beta), -side * math.sin(beta)  # arm direction at straight ahead
    phi0 = math.atan2(uy, ux)
    hx0 = car.steer_servo_x - rs
    tie = math.hypot(ra * ux - hx0, side * w + ra * uy)
    hx, hy = car.steer_servo_x - rs * math.cos(servo), -rs * math.sin(servo)
    dx, dy = hx, hy - side * w  # horn tip relative to the kingpin
    dist = math.hypot(dx, dy)
    c = max(-1.0, min(1.0, (ra * ra + dist * dist - tie * tie) / (2 * ra * dist)))
    psi = math.atan2(dy, dx)
    # the branch the linkage is assembled in: the one through the straight-ahead arm
    c0 = (ra * ra + hx0 * hx0 + w * w - tie * tie) / (2 * ra * math.hypot(hx0, w))
    psi0 = math.atan2(-side * w, hx0)
    sgn = 1.0 if abs(math.remainder(psi0 + math.acos(max(-1.0, min(1.0, c0))) - phi0, 2 * math.pi)) < 1e-6 else -1.0
    return math.remainder(psi + sgn * math.acos(c) - phi0, 2 * math.pi)


def linkage_ratio(car: CarParams) -> float:
    """Road-wheel angle per servo angle at straight ahead (the single track's: mean of both wheels)."""
    h = 1e-6
    return sum(_wheel_angle(s * h, side, car) * s for s in (1, -1) for side in (1, -1)) / (4 * h)


def road_wheel_angle(servo_cmd: float, car: CarParams, ratio: float) -> float:
    """Single-track road-wheel angle (mean of left and right) for the servo output expressed
    as the road-wheel angle its pulse calibration promises (``servo_cmd`` / ``ratio`` is the
    horn angle): equal to it at small angles, not at large ones."""
    servo = servo_cmd / ratio
    return 0.5 * (_wheel_angle(servo, 1, car) + _wheel_angle(servo, -1, car))


def spool_moment(vx: float, r: float, Fx: float, car: CarParams) -> float:
    """Yaw moment [N m] of a locked rear axle: both wheels turn at one speed omega, so the
    inner and outer wheels slip differently. Each wheel's force is Cx/2 times its slip
    (omega R - v)/v at its own ground speed v = vx -+ r t/2; omega follows from the drive
    force the axle must deliver (quasi-static: the wheels spin up far faster than the car)."""
    h = car.track / 2
    vl, vr = max(vx - h * r, 0.1), max(vx + h * r, 0.1)
    cw = car.Cx / 2
    wR = (Fx / cw + 2.0) / (1.0 / vl + 1.0 / vr)
    return h * (cw * (wR / vr - 1.0) - cw * (wR / vl - 1.0))


def _mf(alpha, C, Fz, mu, shape):
    """Magic-formula side force with the given cornering stiffness at small slip."""
    D = mu * Fz
    B = C / (shape * D)
    return D * math.sin(shape * math.atan(B * alpha))


def simulate(car: CarParams, effects: Effects, t: np.ndarray, steer_plan: np.ndarray,
             v_ref: np.ndarray, driver=None, pulse_rise_us: np.ndarray | None = None) -> Trajectory:
    """Integrate the car over the grid ``t`` (uniform, starting at 0) with RK4: the whole
    run as one chunk of ``simulate_chunks`` (see there)."""
    chunk = next(simulate_chunks(car, effects, t, steer_plan, v_ref, driver, pulse_rise_us))
    return chunk.trajectory(t, v_ref)


@dataclass
class Chunk:
    """Rows ``i0`` .. ``i0 + len(out) - 1`` of the truth, as the integrator left them."""

    i0: int
    out: np.ndarray  # (m, 13) states at the start of each step
    aux: np.ndarray  # (m, 7) Fyf, Fyr, delta, dvx, dvy, dr, Fx
    delta_cmd: np.ndarray
    switches: dict  # steps (whole-run indices) with a falling edge inside
    pulses: np.ndarray  # every servo pulse width [us] (shared; complete after the last chunk)
    rise: np.ndarray  # their rising edges [us]
    rhs: object
    spool: bool
    dt: float  # the integration step, t[1] - t[0]

    def trajectory(self, t: np.ndarray, v_ref: np.ndarray) -> Trajectory:
        """These rows as a Trajectory; ``t`` and ``v_ref`` are the whole run's (or this
        chunk's own rows of them, when ``i0`` is 0 and it is the whole run)."""
        rows = slice(self.i0, self.i0 + len(self.out))
        out, aux = self.out, self.aux
        X, Y, psi, vx, vy, r = (out[:, k] for k in range(6))
        dvx, dvy, dr = aux[:, 3], aux[:, 4], aux[:, 5]
        sw = dict(self.switches, step=self.switches["step"] - self.i0)
        tr = Trajectory(t=t[rows], delta_cmd=self.delta_cmd, delta=aux[:, 2], vx=vx, vy=vy, r=r,
                        r_dot=dr, ax=dvx - vy * r, ay=dvy + vx * r, phi=out[:, 9], s=out[:, 11],
                        x=X, y=Y, psi=psi, steer_pulses_us=self.pulses, Fx=aux[:, 6], states=out, rhs=self.rhs,
                        steer_rise_us=self.rise, switches=sw, dt_step=self.dt)
        tr.v_ref = np.asarray(v_ref[rows], float)
        tr.spool = self.spool
        return tr


def simulate_chunks(car: CarParams, effects: Effects, t: np.ndarray, steer_plan: np.ndarray,
                    v_ref: np.ndarray, driver=None, pulse_rise_us: np.ndarray | None = None,
                    chunk_steps: int | None = None):
    """Integrate the car over the grid ``t`` (uniform, starting at 0) with RK4, yielding
    ``Chunk`` s of ``chunk_steps`` rows (default: the whole run in one). The state is
    carried from chunk to chunk, so the rows are those of the whole-run integration, bit
    for bit; a long run need not hold every row at once.

    ``steer_plan`` is the road-wheel angle the driver wants [rad] on the grid, or
    ``driver(x, y, psi, vx)`` returns it in closed loop. Either way the servo
    receives it as a ~50 Hz train of integer-microsecond pulses whose rising edges
    are ``pulse_rise_us`` (default: ``servo_rise_times_us`` with seed 0), and that
    held, quantised command is what the truth applies, from the pulse's falling
    edge to the microsecond (the step that holds the edge is split there). That is
    also what the car's firmware measures. ``v_ref`` is the speed the throttle
    holds [m/s].
    """
    dt = float(t[1] - t[0])
    n = len(t)
    m, a, b, Iz, Cf, Cr = car.mass, car.a, car.b, car.Iz, car.Cf, car.Cr
    Fzf, Fzr = car.axle_loads()
    lag = "actuator_lag" in effects
    relax = "tyre_relaxation" in effects
    roll = "body_roll" in effects
    sat = "tyre_saturation" in effects
    linkage = "steering_nonlinearity" in effects
    spool = "locked_diff" in effects
    trim = "steer_offset" in effects
    ratio = linkage_ratio(car) if linkage else 1.0
    steer_hooks = [e.steer_angle for e in effects.custom if e.steer_angle is not None]
    body_hooks = [e.body_loads for e in effects.custom if e.body_loads is not None]
    wn = 2 * math.pi * car.roll_freq
    zeta = car.roll_damping
    k_speed = 4.0  # 1/s, speed loop gain (throttle driver)

    def side_forces_ss(vx, vy, r, delta):
        vxe = max(vx, 0.3)  # below walking pace the slip angles are meaningless
        af = delta - math.atan2(vy + a * r, vxe)
        ar = -math.atan2(vy - b * r, vxe)
        if sat:
            return _mf(af, Cf, Fzf, car.mu, car.mf_shape), _mf(ar, Cr, Fzr, car.mu, car.mf_shape)
        return Cf * af, Cr * ar

    def rhs(state, dcmd, vref):
        X, Y, psi, vx, vy, r, delta, Fyf, Fyr, phi, phid, s, vint = state
        if lag:
            ddelta = (dcmd - delta) / car.tau_steer
            ddelta = max(-car.steer_rate_max, min(car.steer_rate_max, ddelta))
        else:
            ddelta = 0.0
            delta = dcmd
        servo = delta  # the servo's output, in the road-wheel radians its calibration promises
        if trim:  # the horn sits off centre: the linkage is driven from the trimmed angle
            servo = servo + car.steer_trim
            delta = servo
        if linkage:
            delta = road_wheel_angle(servo, car, ratio)
        for hook in steer_hooks:
            delta = float(hook(delta, car))
        Ff_ss, Fr_ss = side_forces_ss(vx, vy, r, delta)
        if relax:
            vxe = max(vx, 0.3)
            dFyf = vxe / car.sigma_f * (Ff_ss - Fyf)
            dFyr = vxe / car.sigma_r * (Fr_ss - Fyr)
        else:
            Fyf, Fyr = Ff_ss, Fr_ss
            dFyf = dFyr = 0.0
        if vx < 0.05 and vref <= 0.0:  # parked: nothing moves
            Fyf = Fyr = 0.0
        # throttle/brake: PI speed loop on the rear axle force
        err = vref - vx
        Fx = m * (k_speed * err + 1.0 * vint)
        Fx = max(-m * 6.0, min(m * 6.0, Fx))
        if vx <= 0.0 and Fx < 0.0:
            Fx = 0.0
        Fy_x, Mz_x = 0.0, 0.0
        if spool and vx > 0.3:
            Mz_x += spool_moment(vx, r, Fx, car)
        for hook in body_hooks:
            f, mz = hook({"vx": vx, "vy": vy, "r": r, "delta": delta}, car)
            Fy_x += float(f)
            Mz_x += float(mz)
        cd, sd = math.cos(delta), math.sin(delta)
        dvx = (Fx - Fyf * sd) / m + vy * r
        dvy = (Fyf * cd + Fyr + Fy_x) / m - vx * r
        dr = (a * Fyf * cd - b * Fyr + Mz_x) / Iz
        ay = dvy + vx * r
        if roll:
            dphid = -2 * zeta * wn * phid - wn * wn * (phi - car.roll_gain * ay)
        else:
            dphid = 0.0
        cp, sp = math.cos(psi), math.sin(psi)
        return (vx * cp - vy * sp, vx * sp + vy * cp, r, dvx, dvy, dr, ddelta, dFyf, dFyr,
                phid, dphid, vx, err), (Fyf, Fyr, delta, dvx, dvy, dr, Fx)

    if pulse_rise_us is None:
        pulse_rise_us = servo_rise_times_us(car, float(t[-1]), np.random.default_rng(0))
    rise = np.asarray(pulse_rise_us, dtype=np.int64)
    rise = rise[rise <= round(t[-1] * 1e6)]
    n_pulses = len(rise)
    pulses = np.zeros(n_pulses, dtype=np.int64)
    k_next = 0
    dc = 0.0
    state = [0.0] * 13
    pending = None  # (falling edge [us], command [rad]) of the pulse in flight

    def rk4(state, h, dc, vr, k1=None):
        if k1 is None:
            k1, _ = rhs(state, dc, vr)
        s2 = [x + 0.5 * h * k for x, k in zip(state, k1)]
        k2, _ = rhs(s2, dc, vr)
        s3 = [x + 0.5 * h * k for x, k in zip(state, k2)]
        k3, _ = rhs(s3, dc, vr)
        s4 = [x + h * k for x, k in zip(state, k3)]
        k4, _ = rhs(s4, dc, vr)
        return [x + h / 6.0 * (p + 2 * q + 2 * u + w) for x, p, q, u, w in zip(state, k1, k2, k3, k4)]

    dt_us = dt * 1e6
    chunk_steps = n if chunk_steps is None else max(1, int(chunk_steps))
    spool_on = "locked_diff" in effects
    for i0 in range(0, n, chunk_steps):
        i1 = min(n, i0 + chunk_steps)
        out = np.zeros((i1 - i0, 13))
        aux = np.zeros((i1 - i0, 7))
        delta_cmd = np.zeros(i1 - i0)
        sw_step, sw_t, sw_state, sw_old, sw_new = [], [], [], [], []
        for i in range(i0, i1):
            t0_us = t[i] * 1e6
            # the width of pulse k is set when it starts (the driver's wish at the step that
            # holds the rising edge); the servo takes it at the pulse's end, the falling edge,
            # where the firmware measures it
            while k_next < n_pulses and rise[k_next] < t0_us + dt_us - 1e-6:
                want = driver(state[0], state[1], state[2], state[3]) if driver else float(steer_plan[i])
                us = int(round(car.steer_center_us + want * car.steer_us_per_rad))
                us = max(900, min(2100, us))
                pulses[k_next] = us
                pending = (int(rise[k_next]) + us, (us - car.steer_center_us) / car.steer_us_per_rad)
                k_next += 1
            if pending is not None and pending[0] <= t0_us + 1e-6:  # edge at (or, rounding, just before) t_i
                dc = pending[1]
                pending = None
                if not lag:
                    state[6] = dc
            if i == 0:
                state[6] = dc
            delta_cmd[i - i0] = dc
            vr = float(v_ref[i])
            k1, ax1 = rhs(state, dc, vr)
            out[i - i0] = state
            aux[i - i0] = ax1
            if pending is not None and pending[0] < t0_us + dt_us - 1e-6:
                # the falling edge lies inside this step: integrate up to it, take the command there
                h1 = (pending[0] - t0_us) * 1e-6
                state = rk4(state, h1, dc, vr, k1)
                if not lag:
                    state[6] = dc
                sw_step.append(i)
                sw_t.append(pending[0] * 1e-6)
                sw_state.append(list(state))
                sw_old.append(dc)
                dc = pending[1]
                sw_new.append(dc)
                pending = None
                if not lag:
                    state[6] = dc
                state = rk4(state, dt - h1, dc, vr)
            else:
                state = rk4(state, dt, dc, vr, k1)
            if not lag:
                state[6] = dc
            if state[3] < 0.0:
                state[3] = 0.0
        if i1 == n:
            pulses[k_next:] = pulses[k_next - 1] if k_next else int(car.steer_center_us)
        switches = {"step": np.asarray(sw_step, dtype=int), "t": np.asarray(sw_t, dtype=float),
                    "state": np.asarray(sw_state, dtype=float).reshape(-1, 13),
                    "old": np.asarray(sw_old, dtype=float), "new": np.asarray(sw_new, dtype=float)}
        _check_bounded(out, t[i0:i0 + len(out)], effects)
        yield Chunk(i0=i0, out=out, aux=aux, delta_cmd=delta_cmd, switches=switches, pulses=pulses, rise=rise,
                    rhs=rhs, spool=spool_on, dt=dt)


R_DIVERGED = 50.0  # rad/s: a car yawing faster than 8 turns a second is no car; its motion diverged


def _check_bounded(out: np.ndarray, t: np.ndarray, effects: Effects) -> None:
    """A ValueError, naming the effect files, where the integrated motion went non-finite or diverged
    (a trial user's unstable effect and its nan ended as 'cannot convert float NaN to integer' from
    the ADC, naming nothing)."""
    bad = ~np.all(np.isfinite(out), axis=1) | (np.abs(np.nan_to_num(out[:, 5], nan=np.inf)) > R_DIVERGED)
    if not bad.any():
        return
    k = int(np.flatnonzero(bad)[0])
    files = ", ".join(e.path for e in effects.custom)
    raise ValueError(f"the simulated car's motion diverged at t = {t[k]:.3f} s (its state "
                     f"{'went nan or inf' if not np.all(np.isfinite(out[k])) else f'yawed at {out[k, 5]:.3g} rad/s'})"
                     + (f": the effect file {files} makes it unstable or returns nan there; check its signs "
                        "(ISO 8855: a load that grows with the motion it causes runs away) and units" if files else
                        ": check the car's parameters (--car) and the effects hidden"))


class TrajectoryWindow:
    """The rows of a chunked integration that later computations still need: chunks are
    added at the end as they are integrated, rows no longer needed are dropped from the
    start, so a long run is never held whole. ``trajectory()`` gives the rows held as a
    Trajectory whose outputs (``dense``) equal the whole run's wherever its rows reach."""

    def __init__(self, t: np.ndarray, v_ref: np.ndarray):
        self.t, self.v_ref = t, v_ref  # the whole run's grids (small next to the states)
        self.rows: Chunk | None = None

    @property
    def start(self) -> int:
        return self.rows.i0

    @property
    def end(self) -> int:
        """One past the last row held."""
        return self.rows.i0 + len(self.rows.out)

    def add(self, c: Chunk) -> None:
        w = self.rows
        if w is None:
            self.rows = c
            return
        if c.i0 != self.end:
            raise ValueError("chunks must be added in order")
        sw = {k: np.concatenate([w.switches[k], c.switches[k]]) for k in w.switches}
        self.rows = Chunk(i0=w.i0, out=np.concatenate([w.out, c.out]), aux=np.concatenate([w.aux, c.aux]),
                          delta_cmd=np.concatenate([w.delta_cmd, c.delta_cmd]), switches=sw, pulses=c.pulses,
                          rise=c.rise, rhs=c.rhs, spool=c.spool, dt=c.dt)

    def keep_from(self, j: int) -> None:
        """Drop the rows before ``j`` (whole-run index)."""
        w = self.rows
        k = min(max(0, j - w.i0), len(w.out) - 1)
        if k == 0:
            return
        keep = w.switches["step"] >= w.i0 + k
        sw = {name: v[keep] for name, v in w.switches.items()}
        self.rows = Chunk(i0=w.i0 + k, out=w.out[k:].copy(), aux=w.aux[k:].copy(),
                          delta_cmd=w.delta_cmd[k:].copy(), switches=sw, pulses=w.pulses, rise=w.rise,
                          rhs=w.rhs, spool=w.spool, dt=w.dt)

    def trajectory(self) -> Trajectory:
        return self.rows.trajectory(self.t, self.v_ref)
