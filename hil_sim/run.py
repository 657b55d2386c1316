"""One simulated run: manoeuvre -> truth dynamics -> sensors -> stimulus for the
simulated board, plus the truth that the tests (and only the tests) may read."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from hil_sim import manoeuvres, sensors, vehicle
from hil_sim.stimulus import Stimulus, VoltRows

# The wiring of the simulated car (as firmware/README.md tells a builder to wire it).
# With four wheel-speed sensors (SimConfig.wheel_speeds) "halls4" replaces "hall".
WIRING = {
    "pico": {"ax": 26, "ay": 27, "yaw": 28, "steer": 2, "hall": 3,
             "halls4": {"fl": 4, "fr": 5, "rl": 3, "rr": 6}},
    "esp32": {"ax": 32, "ay": 33, "az": 34, "yaw": 35, "vbat": 36, "steer": 25, "hall": 26,
              "halls4": {"fl": 27, "fr": 14, "rl": 26, "rr": 13}},
}


@dataclass
class SimConfig:
    plan: manoeuvres.Plan = field(default_factory=manoeuvres.Plan)
    effects: tuple = ()
    effect_files: tuple = ()  # paths of users' truth-side effects (hil_sim.effect_file)
    seed: int = 0
    board: str = "pico"
    rate_hz: int = 500
    batch: int = 10
    ring_size: int | None = None  # None: the firmware's own (1.25 s of samples), as `stid flash` leaves a board
    dt: float = 1e-3  # s, truth integration step
    fs_sig: int = 5000  # Hz, pin voltage grid
    start_ticks: int = 0
    stalls: tuple = ()  # ((at_s, for_s), ...): the host stops reading (MCU overrun)
    car_fault_at: float | None = None  # s: the car's sampler stops (its timer callback raised); the watchdog restarts it
    beta_sensor: float | None = None  # rms noise [rad] of an optical body-slip sensor in the CSV, or None
    wheel_speeds: bool = False  # four hall wheel sensors on the car (firmware SAMPLES4); CSV w_fl..w_rr
    wheel_ppr: int = 1  # hall pulses per wheel revolution (magnets per wheel)
    car: vehicle.CarParams = field(default_factory=vehicle.CarParams)
    sens: sensors.SensorParams = field(default_factory=sensors.SensorParams)


@dataclass
class SimRun:
    cfg: SimConfig
    traj: vehicle.Trajectory | None  # None for a run streamed to its stimulus file (record)
    stimulus: Stimulus
    manoeuvre: manoeuvres.Manoeuvre

    def truth(self) -> dict:
        """Parameters and effects of this run: for tests and benchmarks only."""
        return truth_of(self.cfg)


def truth_of(c: SimConfig) -> dict:
    """Parameters and effects of a run: for tests and benchmarks only."""
    return {
        "car": c.car.as_dict(), "sensors": c.sens.as_dict(), "effects": sorted(c.effects),
        "effect_files": [str(f) for f in c.effect_files],
        "manoeuvre": asdict(c.plan), "seed": c.seed, "board": c.board, "rate_hz": c.rate_hz,
        "wiring": WIRING[c.board], "wheel_speeds": c.wheel_speeds, "wheel_ppr": c.wheel_ppr,
    }


def _prepare(cfg: SimConfig):
    """(effects, rng, manoeuvre, driver, servo rising edges): everything before the truth
    is integrated, with the random draws in their fixed order."""
    if cfg.board not in WIRING:
        raise ValueError(f"unknown board {cfg.board!r}; choose one of {', '.join(WIRING)}")
    from hil_sim.effect_file import load_effect_file

    effects = vehicle.Effects(set(cfg.effects), tuple(load_effect_file(f) for f in cfg.effect_files))
    rng = np.random.default_rng(cfg.seed)
    man = manoeuvres.build(cfg.plan, cfg.dt, rng)
    driver = None
    if man.path is not None:
        L = cfg.car.L
        driver = lambda x, y, psi, vx: manoeuvres.pure_pursuit(man.path, x, y, psi, vx, L)  # noqa: E731
    # the receiver's own clock, from a stream of its own (the other draws stay as they were)
    rise = vehicle.servo_rise_times_us(cfg.car, float(man.t[-1]), np.random.default_rng([cfg.seed, 0x5E7]))
    return effects, rng, man, driver, rise


def _stimulus(cfg: SimConfig, volts, pulses, rise, hall_t, halls) -> Stimulus:
    wiring = WIRING[cfg.board]
    return Stimulus(board=cfg.board, fs_sig=cfg.fs_sig, volts=volts, steer_us=pulses, hall_t_us=hall_t,
                    steer_pin=wiring["steer"], hall_pin=wiring["hall"], steer_rise_us=rise,
                    wheel_halls=None if halls is None else {k: (pin, halls[k]) for k, pin in wiring["halls4"].items()},
                    wheel_ppr=cfg.wheel_ppr, start_ticks=cfg.start_ticks,
                    stalls=[(int(a * 1e6), int(b * 1e6)) for a, b in cfg.stalls],
                    timer_fault_us=None if cfg.car_fault_at is None else int(cfg.car_fault_at * 1e6))


def _analog_pins(cfg: SimConfig, volts: dict) -> dict:
    wiring = WIRING[cfg.board]
    return {wiring[ch]: volts[ch] for ch in ("ax", "ay", "az", "yaw", "vbat") if ch in wiring}


def simulate_run(cfg: SimConfig) -> SimRun:
    """The whole run in memory: the truth on its grid and the stimulus (for tests and short runs)."""
    effects, rng, man, driver, rise = _prepare(cfg)
    traj = vehicle.simulate(cfg.car, effects, man.t, man.delta_cmd, man.v_ref, driver=driver,
                            pulse_rise_us=rise)
    t_bias = cfg.plan.still
    tg, volts = sensors.pin_voltages(traj, cfg.car, effects, cfg.sens, cfg.fs_sig, rng, t_bias)
    halls = sensors.wheel_hall_edges_us(traj, cfg.car, cfg.wheel_ppr) if cfg.wheel_speeds else None
    stim = _stimulus(cfg, _analog_pins(cfg, volts), pulses=traj.steer_pulses_us, rise=traj.steer_rise_us,
                     hall_t=sensors.hall_edges_us(traj, cfg.car, cfg.wheel_ppr), halls=halls)
    return SimRun(cfg, traj, stim, man)


BLOCK_S = 4.0  # s of truth per block when streaming: ~1 MB of states, ~5 MB of voltage work
_MARGIN = 3  # truth rows kept beyond what a voltage block reads (float rounding of grid instants)


def write_stimulus(cfg: SimConfig, path: Path, block_s: float = BLOCK_S) -> Stimulus:
    """Simulate the run block by block and write its stimulus file: the same bytes as
    ``simulate_run(cfg).stimulus.write(path)`` with memory bounded by the block, not the run
    (the truth is integrated ``block_s`` at a time with its state carried over, the pin
    voltages follow it, rows no longer needed are dropped). Returns the stimulus without
    its voltages (they are in the file).

    A user's ``sensor_signals`` hook sees whole arrays and may act across time, so with one
    the run is one block."""
    effects, rng, man, driver, rise = _prepare(cfg)
    car, t, n = cfg.car, man.t, len(man.t)
    steps = max(2 * _MARGIN + 2, int(round(block_s / cfg.dt)))
    if any(e.sensor_signals is not None for e in effects.custom):
        steps = n
    n_grid = sensors.grid_size(t[-1], cfg.fs_sig)
    pv = sensors.PinVoltages(car, effects, cfg.sens, cfg.fs_sig, rng, cfg.plan.still, n_grid)
    delay = car.sensor_delay_s if "sensor_delay" in effects else 0.0
    win = vehicle.TrajectoryWindow(t, man.v_ref)
    s = np.empty(n)  # distance and wheel speeds on the truth grid: the edges need the whole run
    wheels = [np.empty(n) for _ in sensors.WHEEL_NAMES] if cfg.wheel_speeds else None
    rows_path = Path(str(path) + ".volts")
    rows = None
    done = 0  # grid points written
    chunk = None
    try:
        for chunk in vehicle.simulate_chunks(car, effects, t, man.delta_cmd, man.v_ref, driver=driver,
                                             pulse_rise_us=rise, chunk_steps=steps):
            win.add(chunk)
            got = slice(chunk.i0, chunk.i0 + len(chunk.out))
            s[got] = chunk.out[:, 11]
            if wheels is not None:
                for w, v in zip(wheels, vehicle.wheel_speeds(chunk.trajectory(t, man.v_ref), car)):
                    w[got] = v
            end = got.stop
            if end == n:
                upto = n_grid
            elif end - 1 - _MARGIN > 0:  # grid points strictly inside the rows held, with a margin
                upto = min(n_grid, max(done, int(t[end - 1 - _MARGIN] * cfg.fs_sig)))
            else:
                upto = done
            if upto > done:
                _, volts = pv.block(win.trajectory(), done, upto)
                pins = _analog_pins(cfg, volts)
                if rows is None:
                    rows = VoltRows(rows_path, pins)
                rows.add(pins)
                done = upto
            # the next block reads the truth from its first instant less the sensor delay
            win.keep_from(int((done / cfg.fs_sig - delay) / cfg.dt) - _MARGIN)
        halls = sensors.wheel_hall_edges_from_speeds_us(t, wheels, cfg.wheel_ppr) if wheels is not None else None
        stim = _stimulus(cfg, {}, pulses=chunk.pulses, rise=chunk.rise,
                         hall_t=sensors.hall_edges_from_distance_us(t, s, car, cfg.wheel_ppr), halls=halls)
        stim.volt_rows = rows
        stim.write(path)
    finally:
        if rows is not None:
            rows.close()
        rows_path.unlink(missing_ok=True)
    return stim


def write_truth(run: SimRun, path: Path) -> None:
    Path(path).write_text(json.dumps(run.truth(), indent=1) + "\n")
