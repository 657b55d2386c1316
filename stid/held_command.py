"""A held command (a staircase: each value from its instant until the next) as the samples of
the models' input.

The models take their input as samples with straight lines between them (a first-order hold).
A servo, a VESC or a speed controller holds each command until the next, so the wheel is driven
by a staircase whose steps fall anywhere between two samples. The command's value *at* each
sample instant puts every step on the sample after it; drawn with lines between samples, the
step then acts from half a sample before that sample, whatever its true time: an error of up to
half a sample either way that depends on where the commands fall against the sampling (yaw
inertia moves ~5% per ms of steer timing; on a new user's exact single-track bags, 50 Hz commands
and a 200 Hz IMU, Iz came out -11% to -17% with a servo lag, narrow intervals missing the truth).

Each sample as the staircase's mean over the sample period centred on it puts every step at its
own time: the first-order hold of those means has the staircase's integral (a step at s moves
the line's area by exactly what the step moves the staircase's), so it is delayed by nothing.
"""

from __future__ import annotations

import numpy as np


def interval_means(t: np.ndarray, value: np.ndarray, grid: np.ndarray, h: float) -> np.ndarray:
    """The staircase ``value[i]`` from ``t[i]`` (increasing) until ``t[i + 1]`` (the first value
    also before ``t[0]``, the last after the end) as its mean over ``[g - h/2, g + h/2]`` for each
    instant ``g`` of ``grid`` (spaced ``h``)."""
    t0 = float(t[0]) if len(t) else 0.0
    t = np.asarray(t, float) - t0  # (stamps from the epoch, 1.7e9 s, hold 0.2 us: the sums need them small)
    value = np.asarray(value, float)
    steps = np.concatenate([[True], value[1:] != value[:-1]])  # a command that repeats the last is no step
    t, value = t[steps], value[steps]
    area = np.concatenate([[0.0], np.cumsum(value[:-1] * np.diff(t))])  # the integral at each step
    g = np.asarray(grid, float) - t0
    lo = np.clip(np.searchsorted(t, g - h / 2, side="right") - 1, 0, len(t) - 1)
    hi = np.clip(np.searchsorted(t, g + h / 2, side="right") - 1, 0, len(t) - 1)
    mean = (area[hi] + value[hi] * (g + h / 2 - t[hi]) - area[lo] - value[lo] * (g - h / 2 - t[lo])) / h
    # a period within one hold is that value exactly (a hold is found by its samples being equal)
    return np.where(lo == hi, value[lo], mean)
