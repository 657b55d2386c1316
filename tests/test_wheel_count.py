"""The host's reading of the hall pulse count (host/units.py): 16 bits, counting up."""

import math

import numpy as np

from host.units import pulses_total, wheel_speed


def test_a_count_that_steps_back_is_no_pulse_not_65535():
    # the Pico's count as of its sample instant stepped back by one while parked (firmware
    # 0.3.1): 7 7 6 6 7 8 is one real pulse (7 -> 8), not 65,535 + 2
    assert pulses_total([7, 7, 6, 6, 7, 8]).tolist() == [0, 0, 0, 0, 0, 1]


def test_the_count_wraps_at_65536():
    assert pulses_total([65534, 65535, 0, 1]).tolist() == [0, 1, 2, 3]


def test_speed_over_a_step_back_stays_the_truth():
    # 2 m/s on a wheel of 1 m circumference with one magnet: an edge every 0.5 s; the
    # firmware's count steps back by one for a few samples mid-way. Speed must not jump.
    fs, radius = 100, 1 / (2 * math.pi)
    t = np.arange(0, 5, 1 / fs)
    edges = np.arange(0.25, 5, 0.5)
    count = np.searchsorted(edges, t, side="right")
    last = np.where(count > 0, edges[np.maximum(count - 1, 0)], 0.0)
    count_seen = count.copy()
    count_seen[200:210] -= 1  # stepped back (edge time left as it was)
    t_us = (t * 1e6).astype(np.int64)
    v = wheel_speed(t_us, t_us % (1 << 30), count_seen % 65536, (last * 1e6).astype(np.int64) % (1 << 30),
                    pulses_per_rev=1, radius=radius)
    ok = t > 1.0
    assert np.allclose(v[ok], 2.0, atol=1e-9), v[ok][np.abs(v[ok] - 2) > 1e-9][:5]
