"""The measurement chain that comes with the data: each sensor's output filter.

The ADXL335's bandwidth is set by its output capacitors (5 uF / C: 0.1 uF gives
50 Hz) and the LISY300AL has an internal low-pass (88 Hz); another logger's data
may have been filtered differently, or not at all. The model must filter its
outputs exactly as the data were filtered, so the chain is never assumed:

- an MCAP run takes each channel's ``bandwidth_hz`` from its HELLO (protocol v2);
  a v1 HELLO declares only the part numbers, so the parts' usual bandwidths are
  taken, and the note says so;
- the vehicle file's ``[sensors]`` ``accel_bandwidth_hz`` / ``gyro_bandwidth_hz``
  override either (0 means no filter);
- a CSV with neither has no sensor filter.

A chain is ``{"ay": Hz or 0, "r": Hz or 0, "source": "..."}``; 0 means no filter. A
filter is first-order unless the vehicle file's ``accel_filter_order`` / ``gyro_filter_order``
say 2 (a second-order Butterworth: many IMUs' digital low-pass), kept as ``"ay_order"`` /
``"r_order"``. Its delay at low frequency is 1.41 / (2 pi f) where a first-order one's is
1 / (2 pi f): a 30 Hz filter of the one order declared as the other leaves 2.2 ms, which a fit
reads as a timing error of the steer.
"""

from __future__ import annotations

# what a v1 HELLO's part numbers imply: ADXL335 with the usual 0.1 uF; LISY300AL's own filter
PART_BANDWIDTH_HZ = {"ADXL335": 50.0, "LISY300AL": 88.0}
VEHICLE_KEYS = {"ay": "accel_bandwidth_hz", "r": "gyro_bandwidth_hz"}
ORDER_KEYS = {"ay": "accel_filter_order", "r": "gyro_filter_order"}
CSV_NONE = "CSV: none declared"
ROS_NONE = "ROS bag: none declared"
_NONE = (CSV_NONE, ROS_NONE)
HELLO_CHANNELS = {"ay": "ay", "r": "yaw"}


def _override(chain: dict, vehicle) -> dict:
    sensors = getattr(vehicle, "sensors", None) or {}
    used = [k for k in VEHICLE_KEYS.values() if k in sensors]
    for out, key in VEHICLE_KEYS.items():
        if key in sensors:
            chain[out] = max(float(sensors[key]), 0.0)
    for out, key in ORDER_KEYS.items():
        if int(sensors.get(key, 1)) != 1:
            chain[f"{out}_order"] = int(sensors[key])
    if used:
        keep = chain.get("source") if len(used) < len(VEHICLE_KEYS) and chain.get("source") not in _NONE else ""
        chain["source"] = (keep + "; " if keep else "") + f"vehicle file [sensors] {', '.join(used)}"
    return chain


def from_hello(hello: dict, vehicle) -> dict:
    chain = {"ay": 0.0, "r": 0.0}
    declared, assumed = [], []
    channels = hello.get("channels") or {}
    for out, ch in HELLO_CHANNELS.items():
        c = channels.get(ch) or {}
        if c.get("bandwidth_hz") is not None:
            chain[out] = float(c["bandwidth_hz"])
            declared.append(out)
        elif c.get("part") in PART_BANDWIDTH_HZ:
            chain[out] = PART_BANDWIDTH_HZ[c["part"]]
            assumed.append(f"{out} ({c['part']})")
    src = []
    if declared:
        src.append("HELLO bandwidth_hz")
    if assumed:
        src.append("the parts' usual bandwidth for " + ", ".join(assumed) + " (this HELLO declares none)")
    chain["source"] = "; ".join(src) or "none declared"
    return _override(chain, vehicle)


def from_vehicle(vehicle, source: str = CSV_NONE) -> dict:
    """The chain when the data declare none (a CSV, a ROS bag: ``source`` says which; a
    model's default): the vehicle file's [sensors], else no filter."""
    return _override({"ay": 0.0, "r": 0.0, "source": source}, vehicle)


def undeclared_warnings(runs, vehicle) -> list:
    """A CSV that declares no chain is fitted unfiltered. That is right for another logger's
    unfiltered data, and wrong by percents for filtered sensor outputs (an IMU's digital
    low-pass; a CSV from ``stid export`` or ``stid-sim --csv``): say so once, with the keys that
    settle it and where their values come from."""
    sensors = getattr(vehicle, "sensors", None) or {}
    if all(k in sensors for k in VEHICLE_KEYS.values()):
        return []
    csv = [r.name for r in runs if (r.meta.get("sensor_chain") or {}).get("source") in _NONE]
    if not csv:
        return []
    what = "a ROS bag" if all((r.meta.get("sensor_chain") or {}).get("source") == ROS_NONE for r in runs
                              if r.name in csv) else "a CSV"
    # No numbers are suggested: another logger's IMU (a VESC's, a phone's) filters as it was
    # configured, and our parts' 50 / 88 Hz would be a guess dressed as a value.
    return [f"{', '.join(csv[:3])}{' ...' if len(csv) > 3 else ''}: {what} carries no sensor chain and the "
            "vehicle file declares none, so the model's outputs are not filtered. If the sensors filtered "
            "what was logged (an IMU's digital low-pass, an analog output filter), declare those filters' "
            "bandwidths in Hz, as the logging setup configured them, in the vehicle file ([sensors] "
            "accel_bandwidth_hz, gyro_bandwidth_hz, and accel_filter_order, gyro_filter_order = 2 for a "
            "second-order Butterworth; a CSV from stid export: the values it printed; from "
            "stid-sim --csv: its simulated ADXL335 and LISY300AL, 50 and 88 Hz); if the data are truly unfiltered, declare 0 for both to say so"]


def describe(chain: dict | None) -> str:
    """One line: the filters the model applies to its outputs, and where they come from."""
    if not chain:
        return "sensor chain: no output filter"

    def one(out):
        f = chain.get(out, 0.0)
        kind = "second-order (Butterworth)" if order(chain, out) == 2 else "first-order"
        return f"{out} {kind} {f:g} Hz" if f and f > 0 else f"{out} unfiltered"
    return f"sensor chain: {one('ay')}, {one('r')} (from {chain.get('source', '?')})"


def order(chain: dict | None, out: str) -> int:
    """The order of output ``out``'s filter in ``chain`` (1 unless declared 2)."""
    return int((chain or {}).get(f"{out}_order", 1))
