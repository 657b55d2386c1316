"""One simulated run: manoeuvre -> truth dynamics -> sensors -> stimulus for the
simulated board, plus the truth that the tests (and only the tests) may read."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from hil_sim import manoeuvres, sensors, vehicle
from hil_sim.stimulus import Stimulus

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
    ring_size: int = 256
    dt: float = 1e-3  # s, truth integration step
    fs_sig: int = 5000  # Hz, pin voltage grid
    start_ticks: int = 0
    stalls: tuple = ()  # ((at_s, for_s), ...): the host stops reading (MCU overrun)
    beta_sensor: float | None = None  # rms noise [rad] of an optical body-slip sensor in the CSV, or None
    wheel_speeds: bool = False  # four hall wheel sensors on the car (firmware SAMPLES4); CSV w_fl..w_rr
    wheel_ppr: int = 1  # hall pulses per wheel revolution (magnets per wheel)
    car: vehicle.CarParams = field(default_factory=vehicle.CarParams)
    sens: sensors.SensorParams = field(default_factory=sensors.SensorParams)


@dataclass
class SimRun:
    cfg: SimConfig
    traj: vehicle.Trajectory
    stimulus: Stimulus
    manoeuvre: manoeuvres.Manoeuvre

    def truth(self) -> dict:
        """Parameters and effects of this run: for tests and benchmarks only."""
        c = self.cfg
        return {
            "car": c.car.as_dict(), "sensors": c.sens.as_dict(), "effects": sorted(c.effects),
            "effect_files": [str(f) for f in c.effect_files],
            "manoeuvre": asdict(c.plan), "seed": c.seed, "board": c.board, "rate_hz": c.rate_hz,
            "wiring": WIRING[c.board], "wheel_speeds": c.wheel_speeds, "wheel_ppr": c.wheel_ppr,
        }


def simulate_run(cfg: SimConfig) -> SimRun:
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
    traj = vehicle.simulate(cfg.car, effects, man.t, man.delta_cmd, man.v_ref, driver=driver,
                            pulse_rise_us=rise)
    t_bias = cfg.plan.still
    tg, volts = sensors.pin_voltages(traj, cfg.car, effects, cfg.sens, cfg.fs_sig, rng, t_bias)
    wiring = WIRING[cfg.board]
    pins = {wiring[ch]: volts[ch] for ch in ("ax", "ay", "az", "yaw", "vbat") if ch in wiring}
    halls = None
    if cfg.wheel_speeds:
        edges = sensors.wheel_hall_edges_us(traj, cfg.car, cfg.wheel_ppr)
        halls = {k: (pin, edges[k]) for k, pin in wiring["halls4"].items()}
    stim = Stimulus(board=cfg.board, fs_sig=cfg.fs_sig, volts=pins, steer_us=traj.steer_pulses_us,
                    hall_t_us=sensors.hall_edges_us(traj, cfg.car, cfg.wheel_ppr), steer_pin=wiring["steer"],
                    hall_pin=wiring["hall"], steer_rise_us=traj.steer_rise_us, wheel_halls=halls,
                    wheel_ppr=cfg.wheel_ppr, start_ticks=cfg.start_ticks,
                    stalls=[(int(a * 1e6), int(b * 1e6)) for a, b in cfg.stalls])
    return SimRun(cfg, traj, stim, man)


def write_truth(run: SimRun, path: Path) -> None:
    Path(path).write_text(json.dumps(run.truth(), indent=1) + "\n")
