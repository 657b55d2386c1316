"""A run kept as one CSV file per ROS topic, in a directory: what ``rostopic echo -p
/imu > imu.csv`` writes, or a logger that saved each topic's messages as a table. It is
read like a bag (stid.ros.to_run): the vehicle file's ``[ros]`` names the files, and
``[ros.fields]`` the columns holding each message field.

```toml
[ros]
imu = "imuData.csv"
odometry = "odomData.csv"
steering = "commandData.csv"

[ros.fields]                 # message field = column or expression of that file's columns
stamp = "s + ns * 1e-9"      # the header stamp [s], in every file
"linear_acceleration.x" = "ax"
"twist.twist.linear.x" = "vx"
"drive.steering_angle" = "delta"
```

A field left out is read from ``rostopic echo -p``'s column for it (``field.`` and the
field's path; the stamp from ``field.header.stamp`` [ns]).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stid.errors import InputError
from stid.ros.bag import Topic
from stid.ros.message_types import ACKERMANN, FLOAT64, IMU, ODOMETRY

ROLE_TYPE = {"imu": IMU, "odometry": ODOMETRY}
STAMP_KEY = "stamp"


def names_files(table: dict) -> bool:
    """Whether the [ros] table names CSV files rather than topics."""
    return any(str(table.get(k, "")).lower().endswith(".csv") for k in ("imu", "odometry", "steering"))


class TopicFiles:
    """Per-topic CSVs read as a bag: the same ``topics``, ``listing()`` and ``read()``."""

    kind = "files"
    label = "directory of topic CSVs"

    def __init__(self, path, table: dict):
        self.path = Path(path)
        self.fields = dict(table.get("fields", {}))
        self.frames = {}
        self.topics = {}
        for role in ("imu", "odometry", "steering"):
            name = table.get(role)
            if name is None:
                raise InputError(f"{self.path} is a directory of topic CSVs: name the {role} file in the vehicle "
                                 f"file's [ros], e.g. {role} = \"{role}.csv\"")
            file = self.path / name
            if not file.is_file():
                have = ", ".join(sorted(p.name for p in self.path.glob("*.csv"))) or "no CSV files"
                raise InputError(f"[ros] {role} = \"{name}\": {self.path} has no such file; it has {have}")
            frame = _read(file)
            self.frames[name] = frame
            self.topics[name] = Topic(name, self._msgtype(role, name, frame), len(frame))

    def __enter__(self) -> "TopicFiles":
        return self

    def __exit__(self, *exc) -> None:
        pass

    def _msgtype(self, role, name, frame) -> str:
        if role in ROLE_TYPE:
            return ROLE_TYPE[role]
        ackermann = "drive.steering_angle"
        if ackermann in self.fields or f"field.{ackermann}" in frame.columns:
            return ACKERMANN
        if "data" in self.fields or "field.data" in frame.columns:
            return FLOAT64
        raise InputError(f"[ros] steering = \"{name}\": no column for the steering command; map it in [ros.fields]: "
                         f"\"drive.steering_angle\" = \"COLUMN\" (a road-wheel angle, rad) or \"data\" = \"COLUMN\" "
                         f"(a servo command); its columns: {', '.join(map(str, frame.columns))}")

    def listing(self) -> str:
        return ", ".join(t.describe() for t in self.topics.values())

    def read(self, wanted: dict) -> dict:
        from stid import csv_map

        out = {}
        for name, fields in wanted.items():
            frame = self.frames[name]
            where = str(self.path / name)
            cols = {}
            for f in fields:
                if f in ("header.stamp.sec", "header.stamp.nanosec"):
                    continue
                expr = self.fields.get(f, f"field.{f}")
                cols[f] = _numbers(csv_map.apply(frame, {f: expr}, where)[f], f, where)
            stamp = self.fields.get(STAMP_KEY)
            if stamp is None and "field.header.stamp" in frame.columns:
                col = frame["field.header.stamp"]
                # nanoseconds since the epoch: as float64 they would keep only 256 ns
                ns = (col.to_numpy(np.int64) if col.dtype.kind in "iu"
                      else _numbers(col, "field.header.stamp", where, stamp=True).astype(np.int64))
            elif stamp is not None:
                ns = np.round(_numbers(csv_map.apply(frame, {STAMP_KEY: stamp}, where)[STAMP_KEY], STAMP_KEY, where,
                                       stamp=True)
                              * 1e9).astype(np.int64)
            else:
                raise InputError(f"{where}: no time column: map the stamp in [ros.fields], e.g. stamp = "
                                 f"\"t\" (seconds); its columns: {', '.join(map(str, frame.columns))}")
            if "header.stamp.sec" in fields:
                cols["header.stamp.sec"] = (ns // 1_000_000_000).astype(float)
                cols["header.stamp.nanosec"] = (ns % 1_000_000_000).astype(float)
            cols["t_log"] = ns  # (a file has no receive times: its stamps stand in for them)
            out[name] = cols
        return out


def _read(file: Path):
    from stid import csv_map

    return csv_map.read(file)[0]


def _numbers(series, what, where, stamp: bool = False) -> np.ndarray:
    """A column as numbers; a field's that are missing stay NaN (a message without a measurement:
    the importer drops it as lost, stid.ros.to_run._read), a time's refuse the file."""
    import pandas as pd

    x = pd.to_numeric(series, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(x)
    if bad.any() and stamp:
        raise InputError(f"{where}: '{what}' has {int(bad.sum())} missing or non-numeric value(s) (first at data row "
                         f"{int(np.flatnonzero(bad)[0]) + 1}); fill or drop those rows")
    return x
