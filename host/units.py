"""Datasheet defaults: raw counts -> volts -> SI, from the HELLO content.

This is the conversion the logger uses for its status line and ``stid export``
uses until ``stid calibrate`` refines offsets and sensitivities.

ADXL335: ratiometric, zero g at Vs/2, Vs/10 per g (300 mV/g at 3 V). On our
boards the sensor supply is the ADC reference, so Vs = vref.
LISY300AL: absolute, 1.65 V at zero rate, 3.3 mV per deg/s.
"""

from __future__ import annotations

import math

import numpy as np

G = 9.81
MISSING = 0xFFFF
GYRO_ZERO_V = 1.65
GYRO_V_PER_DPS = 3.3e-3


V_DRIVING = 1.0  # m/s: slower than this the single track is not fitted (stid.fit.dataset.V_MOVING)


def counts_to_volts(counts, hello: dict):
    adc = hello.get("adc", {})
    c = np.asarray(counts, dtype=float)
    c = np.where(c == MISSING, np.nan, c)
    if adc.get("unit") == "mV":
        return c / 1000.0
    bits = int(adc.get("bits", 12))
    return c / ((1 << bits) - 1) * float(adc.get("vref", 3.3))


def supply_volts(hello: dict) -> float:
    return float(hello.get("adc", {}).get("vref", 3.3))


def accel_si(counts, hello: dict):
    """ADXL335 counts -> specific force [m/s^2] with datasheet zero and sensitivity."""
    vs = supply_volts(hello)
    v = counts_to_volts(counts, hello)
    return (v / vs - 0.5) * 10.0 * G


def yaw_rate_si(counts, hello: dict):
    """LISY300AL counts -> yaw rate [rad/s] with datasheet zero and sensitivity."""
    v = counts_to_volts(counts, hello)
    return np.radians((v - GYRO_ZERO_V) / GYRO_V_PER_DPS)


def clipped(counts, hello: dict):
    """True where a reading sits at the ADC's end of range (or the ESP32's linear limit)."""
    c = np.asarray(counts)
    v = counts_to_volts(c, hello)
    adc = hello.get("adc", {})
    top = (1 << int(adc.get("bits", 12))) - 1
    clip_v = hello.get("adc_clip_v")
    out = (c == 0) | ((c == top) & (adc.get("unit") != "mV"))
    if clip_v:
        out |= v >= float(clip_v) - 0.005
    return out & (c != MISSING)


def pulses_total(wheel_count) -> np.ndarray:
    """Pulses since the first sample, from the 16-bit wheel count of each sample.

    Steps between samples are signed 16-bit (a wrap past 65535 is +1, not -65535), and
    the total never goes back: a count one lower than the sample before (the Pico's
    count as of its sample instant stepped back by one while parked, firmware before
    0.3.2) is no pulse, and counting up to where it was is no pulse either -- never
    +65,535. A gap of more than 32,767 pulses between two received samples (minutes of
    lost frames at speed) cannot be told from a step back and is read as one.
    """
    c = np.asarray(wheel_count, dtype=np.int64)
    steps = (np.diff(c) + 32768) % 65536 - 32768
    return np.maximum.accumulate(np.concatenate([[0], np.cumsum(steps)]))


def wheel_speed(t_mcu_us, t_raw_us, wheel_count, wheel_t_us, pulses_per_rev: int, radius: float,
                mod: int = 1 << 30, centred: bool = False):
    """Wheel ground speed [m/s] from hall pulse counts and the time of the latest pulse;
    NaN where the samples cannot tell it.

    ``t_mcu_us`` is the unwrapped sample time, ``t_raw_us`` the same time as sent
    (mod 2^30); the edge time is unwrapped against it. Between two edges the speed
    is (pulses between them) x (distance per pulse) / (time between them), which is
    exact to the edge timestamps rather than to the sample period. When no edge
    has come for longer than twice the last period, the wheel is slowing: the
    speed is bounded by one pulse over the time since the last edge.

    The count is 16 bits and only counts up; see ``pulses_total`` for a count that
    goes back.

    The first sample of a stretch carries the latest edge before it (its time and the
    count), so the first interval ends at the stretch's first new edge. Before that the
    speed is unknown (NaN) when an edge came recently (within one pulse at ``V_DRIVING``:
    the wheel may be turning at any speed, e.g. after a burst of lost frames at 4 m/s);
    a wheel with no edge for longer is taken as standing (0), the convention the
    stand-still detection relies on.
    """
    t = np.asarray(t_mcu_us, dtype=np.int64)
    count = np.asarray(wheel_count, dtype=np.int64)
    age = (np.asarray(t_raw_us, dtype=np.int64) - np.asarray(wheel_t_us, dtype=np.int64)) % mod
    edge = t - age  # unwrapped time of the latest edge, per sample
    total = pulses_total(wheel_count)
    per_pulse = 2 * math.pi * radius / pulses_per_rev
    new = np.flatnonzero(np.diff(total) > 0) + 1  # samples at which pulses arrived
    if len(t) and count[0] != 0:  # an edge came before the stretch (at boot the count is 0 and no edge was)
        new = np.concatenate([[0], new])
    since = (t - edge) * 1e-6
    # before the first interval: a recent edge says the wheel turns, at a speed not known yet
    recent = (since < per_pulse / V_DRIVING) & ((count != 0) | (total > 0))
    v = np.zeros(len(t))
    if len(new) < 2:
        return np.where(recent, np.nan, v)
    dt = np.diff(edge[new]) * 1e-6
    dn = np.diff(total[new])
    seg_v = np.where(dt > 0, dn * per_pulse / np.where(dt > 0, dt, 1), 0.0)
    seg = np.searchsorted(new[1:], np.arange(len(t)), side="right") - 1  # latest complete segment
    v = np.where(seg >= 0, seg_v[np.maximum(seg, 0)], 0.0)
    if centred:
        # Held from edge to edge, each value is the mean speed over the interval that ended
        # at its edge: the speed lags by one to one and a half edge periods (~70 ms at 4 m/s
        # with one magnet), which a speed that changes with the steering turns into model
        # error. Centred: each mean placed at its interval's middle, linear in between.
        mid = 0.5 * (edge[new][:-1] + edge[new][1:]).astype(float)
        v = np.where(seg >= 0, np.interp(t.astype(float), mid, seg_v), 0.0)
    period = np.where(v > 0, per_pulse / np.where(v > 0, v, 1), np.inf)
    slowing = since > 2 * period
    v = np.where(slowing, np.minimum(v, per_pulse / np.maximum(since, 1e-6)), v)
    return np.where((seg < 0) & recent, np.nan, v)


WHEEL_COLUMNS = {"fl": "w_fl", "fr": "w_fr", "rl": "w_rl", "rr": "w_rr"}
_WHEEL_FIELDS = (("wheel_count", "wheel_t_us"), ("wheel1_count", "wheel1_t_us"),
                 ("wheel2_count", "wheel2_t_us"), ("wheel3_count", "wheel3_t_us"))


def declared_wheels(hello: dict) -> list:
    """The hall sensors a HELLO declares, in record order: [{pin, pulses_per_rev, wheel}].
    Protocol 2 lists them in ``wheels``; protocol 1 has the one ``wheel``."""
    wheels = hello.get("wheels")
    if wheels is None:
        wheels = [hello["wheel"]] if isinstance(hello.get("wheel"), dict) else []
    return list(wheels[:len(_WHEEL_FIELDS)])


def wheel_speeds(t_mcu_us, samples, hello: dict, mod: int = 1 << 30, centred: bool = False) -> dict:
    """Angular speed [rad/s] of every wheel the HELLO declares, from its hall pulses.

    ``t_mcu_us`` is the unwrapped sample time, ``samples`` the sample array (fields
    ``t_us``, ``wheel_count``/``wheel_t_us`` and, for four wheels, ``wheel1_count``
    ... ``wheel3_t_us``, as ``host.mcap_read.read_log(path).samples`` has them).
    Returns ``{"w_fl": array, ...}`` keyed by the declared position (``w_<name>`` for
    a position other than fl, fr, rl, rr, e.g. ``w_rear`` from a protocol 1 HELLO),
    each by the edge-period method of ``wheel_speed`` with that wheel's
    ``pulses_per_rev``. A wheel whose fields the samples do not carry (edge time
    0xFFFFFFFF) is NaN. No wheels declared (no HELLO): an empty dict. ``centred`` as
    in ``wheel_speed``.
    """
    out = {}
    names = samples.dtype.names
    for k, w in enumerate(declared_wheels(hello)):
        pos = str(w.get("wheel", "rl"))
        key = WHEEL_COLUMNS.get(pos, "w_" + pos)
        count_f, t_f = _WHEEL_FIELDS[k]
        if t_f not in names:
            out[key] = np.full(len(samples), np.nan)
            continue
        edge_t = np.asarray(samples[t_f], dtype=np.int64)
        absent = edge_t == 0xFFFFFFFF
        # radius 1 m: ground speed per metre of radius is the angular speed
        v = wheel_speed(t_mcu_us, samples["t_us"], samples[count_f], np.where(absent, 0, edge_t),
                        int(w.get("pulses_per_rev", 1)), 1.0, mod, centred)
        out[key] = np.where(absent, np.nan, v)
    return out
