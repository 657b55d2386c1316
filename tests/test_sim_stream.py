"""The simulator in blocks (stid-sim --fast): the truth integrated chunk by chunk with its
state carried over, the pin voltages computed block by block, the stimulus file written
as it goes. It must be the whole-run simulation bit for bit, and its memory must not
grow with the run's length the way holding every state row would."""

import math
import subprocess
import sys

import numpy as np
import pytest

from hil_sim import sensors, vehicle
from hil_sim.manoeuvres import Plan
from hil_sim.run import SimConfig, simulate_run, write_stimulus

CAR = vehicle.CarParams()

CONFIGS = {
    # every effect, four wheel sensors, a speed that changes (track), two magnets per wheel
    "all_effects": SimConfig(plan=Plan(duration=5, speed_profile="track"), effects=vehicle.EFFECT_NAMES,
                             seed=3, wheel_speeds=True, wheel_ppr=2),
    # a closed-loop driver (pure pursuit) and the ESP32's pins
    "driver_esp32": SimConfig(plan=Plan(name="double_lane_change", duration=4), board="esp32",
                              effects=("actuator_lag", "sensor_delay", "vibration"), seed=1),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
@pytest.mark.parametrize("block_s", [0.37, 2.0])
def test_streamed_stimulus_is_the_whole_run_bit_for_bit(tmp_path, name, block_s):
    cfg = CONFIGS[name]
    whole = tmp_path / "whole.bin"
    simulate_run(cfg).stimulus.write(whole)
    streamed = tmp_path / "streamed.bin"
    write_stimulus(cfg, streamed, block_s=block_s)
    assert streamed.read_bytes() == whole.read_bytes()
    assert [p.name for p in tmp_path.iterdir()] != [] and not (tmp_path / "streamed.bin.volts").exists()


def test_chunks_are_the_whole_integration():
    cfg = CONFIGS["all_effects"]
    from hil_sim.run import _prepare

    effects, _, man, driver, rise = _prepare(cfg)
    whole = vehicle.simulate(CAR, effects, man.t, man.delta_cmd, man.v_ref, driver=driver, pulse_rise_us=rise)
    chunks = list(vehicle.simulate_chunks(CAR, effects, man.t, man.delta_cmd, man.v_ref, driver=driver,
                                          pulse_rise_us=rise, chunk_steps=777))
    assert len(chunks) > 5
    for name in ("vx", "vy", "r", "ay", "ax", "s", "delta", "delta_cmd", "phi"):
        got = np.concatenate([getattr(c.trajectory(man.t, man.v_ref), name) for c in chunks])
        assert np.array_equal(got, getattr(whole, name)), name
    assert np.array_equal(chunks[-1].pulses, whole.steer_pulses_us)
    steps = np.concatenate([c.switches["step"] for c in chunks])
    assert np.array_equal(steps, whole.switches["step"])


def _circle(duration=10.0, vx=4.0, r=0.5, dt=1e-3):
    """A car on a steady circle, written here from kinematics: ay = vx r, the heading
    turns at r, the distance grows at vx."""
    t = np.arange(int(round(duration / dt))) * dt
    n = len(t)
    const = lambda v: np.full(n, float(v))  # noqa: E731
    return vehicle.Trajectory(t=t, delta_cmd=const(0.05), delta=const(0.05), vx=const(vx), vy=const(0.0),
                              r=const(r), r_dot=const(0.0), ax=const(0.0), ay=const(vx * r), phi=const(0.0),
                              s=vx * t, x=vx / r * np.sin(r * t), y=vx / r * (1 - np.cos(r * t)), psi=r * t,
                              steer_pulses_us=np.zeros(0, int), Fx=const(0.0))


def test_voltage_blocks_on_a_hand_written_circle_follow_the_datasheets():
    tr = _circle()
    sens = sensors.SensorParams()
    n = sensors.grid_size(tr.t[-1], 5000)
    _, whole = sensors.PinVoltages(CAR, vehicle.Effects(set()), sens, 5000, np.random.default_rng(7), 0.0, n).block(tr, 0, n)
    pv = sensors.PinVoltages(CAR, vehicle.Effects(set()), sens, 5000, np.random.default_rng(7), 0.0, n)
    cuts = [0, 1, 4999, 12345, 30000, n]
    parts = [pv.block(tr, a, b)[1] for a, b in zip(cuts[:-1], cuts[1:])]
    for name in whole:
        assert np.array_equal(np.concatenate([p[name] for p in parts]), whole[name]), name
    # LISY300AL: 1.65 V + 3.3 mV per deg/s; ADXL335 at 3.3 V: Vs/2 + Vs/10 per g
    assert np.mean(whole["yaw"]) == pytest.approx(1.65 + 3.3e-3 * math.degrees(0.5), abs=1e-3)
    assert np.mean(whole["ay"]) == pytest.approx(1.65 + 0.33 * 4.0 * 0.5 / 9.81, abs=1e-3)
    with pytest.raises(ValueError, match="must follow each other"):
        pv.block(tr, 0, 10)


def test_hall_edges_from_distance_on_a_straight_line():
    tr = _circle(duration=3.0, vx=2.0)
    circ = 2 * math.pi * CAR.wheel_radius / 3
    k = np.arange(1, int(tr.s[-1] // circ) + 1)
    assert np.array_equal(sensors.hall_edges_from_distance_us(tr.t, tr.s, CAR, 3), np.round(k * circ / 2.0 * 1e6))


_PEAK = """
import resource, sys
from hil_sim.manoeuvres import Plan
from hil_sim.run import SimConfig, write_stimulus
write_stimulus(SimConfig(plan=Plan(duration=float(sys.argv[1]))), sys.argv[2])
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def test_streamed_memory_does_not_hold_the_run(tmp_path):
    """Between a short and a long run the peak grows by less than 20 doubles per truth step:
    the whole-run simulation holds 20 per step in its states alone (13 states, 7 outputs),
    besides ~20 more per 5 kHz grid point; the stream keeps only the inputs and the distance."""
    def peak_kb(seconds):
        out = subprocess.run([sys.executable, "-c", _PEAK, str(seconds), str(tmp_path / f"s{seconds}.bin")],
                             capture_output=True, text=True, check=True)
        return int(out.stdout.split()[-1])

    short, long = 5.0, 65.0
    grown = (peak_kb(long) - peak_kb(short)) * 1024
    assert grown < 20 * 8 * (long - short) / 1e-3
