"""A soft timer (ESP32) queues its callbacks behind a blocking write and runs them in a
burst: successive samples can carry one time stamp. That is one run, not a restart.
Every full HELLO (each 10 s) used to cut an ESP32 run into 10 s pieces, which cost
Cf -0.2% and Iz -0.5% against the same seed on a Pico."""

import numpy as np

from stid.load import _pieces


def _samples(t, index, segment=None):
    s = np.zeros(len(t), dtype=[("t_mcu_us", "i8"), ("index", "u4"), ("segment", "i4")])
    s["t_mcu_us"], s["index"] = t, index
    s["segment"] = 0 if segment is None else segment
    return s


def test_a_burst_of_queued_samples_is_one_piece():
    # three callbacks queued during a 7 ms write run at one instant; the index goes on
    t = np.array([0, 2000, 4000, 11000, 11000, 11000, 12000, 14000])
    assert _pieces(_samples(t, np.arange(8))) == [(0, 8)]


def test_a_restart_an_unplug_and_time_going_back_still_cut():
    t = np.array([0, 2000, 4000, 4000, 6000])  # one time stamp, the index does not advance: a duplicate
    assert len(_pieces(_samples(t, np.array([0, 1, 2, 2, 3])))) == 2
    t = np.array([0, 2000, 4000, 900_000, 902_000])  # 0.9 s of nothing: an unplug
    assert len(_pieces(_samples(t, np.arange(5)))) == 2
    t = np.array([0, 2000, 4000, 1000, 3000])  # time going back
    assert len(_pieces(_samples(t, np.arange(5)))) == 2
    seg = np.array([0, 0, 0, 1, 1])  # the firmware restarted
    assert len(_pieces(_samples(np.arange(5) * 2000, np.arange(5), seg))) == 2


def test_an_esp32_run_past_its_full_hello_loads_as_one_run(tmp_path, rc_vehicle):
    from hil_sim.manoeuvres import Plan
    from hil_sim.record import record
    from hil_sim.run import SimConfig
    from stid.load import load_runs

    path = tmp_path / "esp32.mcap"
    record(SimConfig(plan=Plan(name="random_steer", duration=12.0, speed=4.0, steer_amp=0.04), seed=3,
                     board="esp32"), path)
    runs = load_runs([path], rc_vehicle)
    assert len(runs) == 1, [(r.name, len(r.t)) for r in runs]
    assert any("soft timer" in n for n in runs[0].meta.get("notes", []))
