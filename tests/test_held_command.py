"""A held command (a staircase) as the models' input samples (stid.held_command), against the
staircase's own integral: the models draw straight lines between samples, and those lines
must carry each step at its own time, wherever it falls between two samples."""

from __future__ import annotations

import numpy as np

from stid.held_command import interval_means


def _staircase_integral(t_steps, values, a, b):
    """The exact integral over [a, b] of the staircase (values[i] from t_steps[i]), by hand."""
    edges = np.concatenate([[a], np.clip(t_steps[1:], a, b), [b]])
    return float(np.sum(values * np.diff(edges)))


def test_lines_between_the_samples_carry_each_step_at_its_own_time():
    """The straight lines through the samples (trapezoids) hold the staircase's integral over
    any span whose ends sit in holds: a step at s moves both by the same amount, so the line
    puts it at s. The value at each sample instant misses by up to half a sample per step."""
    rng = np.random.default_rng(4)
    h = 0.005  # a 200 Hz grid
    grid = np.arange(0.0, 2.0, h)
    worst_mean = worst_point = 0.0
    for _ in range(50):
        # 50 Hz commands, their phase against the grid at random, a few held twice (a repeat is no step)
        t_steps = np.sort(rng.uniform(-0.01, 0.01) + np.arange(-0.1, 2.1, 0.02))
        values = rng.normal(0.0, 0.1, len(t_steps))
        values[5::7] = values[4::7][: len(values[5::7])]
        # a span from sample a to sample b, both in the middle of a hold
        a, b = sorted(rng.choice(np.arange(20, len(grid) - 20), 2, replace=False))
        while any(np.min(np.abs(t_steps - grid[k])) < h for k in (a, b)):
            a, b = sorted(rng.choice(np.arange(20, len(grid) - 20), 2, replace=False))
        want = _staircase_integral(t_steps, values, grid[a], grid[b])
        means = interval_means(t_steps, values, grid, h)
        worst_mean = max(worst_mean, abs(np.trapezoid(means[a:b + 1], grid[a:b + 1]) - want))
        point = values[np.clip(np.searchsorted(t_steps, grid, side="right") - 1, 0, None)]
        worst_point = max(worst_point, abs(np.trapezoid(point[a:b + 1], grid[a:b + 1]) - want))
    assert worst_mean < 1e-12, worst_mean
    assert worst_point > 100 * 1e-12, "the yardstick cannot tell a point value from the mean"


def test_a_hold_is_its_value_exactly_whatever_the_clock():
    """Stamps from the epoch (1.7e9 s: doubles hold them to 0.2 us, 6e-6 of a 40 ms period) and a
    command repeated: samples within one hold equal the held value bit for bit (stid finds holds
    and clips by equal samples)."""
    epoch = 1.7e9
    t_steps = epoch + np.array([0.0, 0.0331, 0.0662, 0.0993, 0.2])
    values = np.array([0.1, 0.34, 0.34, 0.34, -0.2])  # held at a clip over three commands
    h = 1 / 24.6
    grid = epoch + 0.05 + h * np.arange(3)
    means = interval_means(t_steps, values, grid, h)
    assert np.all(means[(grid - h / 2 > t_steps[1]) & (grid + h / 2 < t_steps[4])] == 0.34), means
    # and a period across a step is the share of each value
    g = np.array([epoch + 0.0331])
    assert abs(interval_means(t_steps, values, g, 0.01)[0] - (0.5 * 0.1 + 0.5 * 0.34)) < 1e-9
