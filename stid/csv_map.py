"""CSV files from other loggers: their delimiter, and the vehicle file's ``[csv]`` table
that maps each contract column to a source column with a scale and a sign.

```toml
[csv]
t = "time_ms * 0.001"          # s
ay = "-imu_ax"                 # the IMU mounted turned: the car's y is the IMU's -x
r = "`gyro z [deg/s]` * 0.017453"
vx = "speed_kmh / 3.6"
```

A value is a column name or an arithmetic expression of columns (pandas' ``eval``: +, -,
*, /, **, parentheses, numbers); a name that is not a plain identifier is written in
backticks. A contract column the table leaves out is read under its own name.
"""

from __future__ import annotations

import re
from pathlib import Path

from stid.errors import InputError, unknown_key
from stid.run import OPTIONAL, REQUIRED

DELIMITERS = (",", ";", "\t", "|")
_NAMES = {",": "','", ";": "';'", "\t": "tab", "|": "'|'", r"\s+": "spaces"}


def contract_columns() -> tuple:
    return REQUIRED + OPTIONAL


def check_table(table: dict, where: str) -> None:
    """Raise InputError for a ``[csv]`` key that is not a contract column, or a value that is
    not a column name or expression."""

    known = contract_columns()
    for key, value in table.items():
        if key not in known:
            raise unknown_key(where, "column", key, list(known), "[csv]")
        if not isinstance(value, str) or not value.strip():
            raise InputError(f"{where}: [csv] {key} must be a source column or an expression in quotes, e.g. "
                             f"{key} = \"-imu_{key}\" or {key} = \"{key}_raw * 0.001\", got {value!r}")


def delimiter(path: Path) -> tuple[str, str]:
    """``(sep, decimal)`` of a CSV file, from its first lines: the delimiter that splits
    every line into the same number of fields (the most fields wins)."""
    with open(path, "rb") as f:
        head = f.read(65536).decode("utf-8", errors="replace")
    lines = [ln for ln in head.splitlines()[:21] if ln.strip()]
    if len(head) == 65536 and len(lines) > 1:
        lines = lines[:-1]  # the last line read may be cut
    if not lines:
        raise InputError(f"{path} is empty")
    found = []
    for d in DELIMITERS:
        counts = [ln.count(d) for ln in lines]
        if counts[0] > 0 and all(c == counts[0] for c in counts):
            found.append((counts[0], d))
    if found:
        sep = max(found)[1]
    elif len(lines[0].split()) > 1 and all(len(ln.split()) == len(lines[0].split()) for ln in lines):
        sep = r"\s+"
    else:
        raise InputError(f"{path}: cannot tell how its columns are separated (tried ',', ';', tab, '|' and spaces: "
                         f"none splits every line alike); its first line reads {lines[0][:80]!r}")
    data = lines[1:]
    decimal = "."
    # European spreadsheets write decimal commas beside semicolons: "0,25;1,5"
    if sep != "," and data and all(re.search(r"\d,\d", ln) for ln in data) and not any(
            re.search(r"\d\.\d", ln) for ln in data):
        decimal = ","
    return sep, decimal


def read(path: Path, what: str = "not a readable CSV"):
    """``(frame, sep, decimal)``: the file read with its own delimiter, names stripped."""
    import pandas as pd  # only CSV needs it (and it costs a quarter second to import)

    sep, decimal = delimiter(path)
    try:
        frame = pd.read_csv(path, sep=sep, decimal=decimal, engine="python" if len(sep) > 1 else "c")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path} is {what} ({str(e).strip()})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame, sep, decimal


def describe(sep: str, decimal: str) -> str:
    return f"{_NAMES[sep]}-separated" + (", decimal commas" if decimal == "," else "")


def apply(df, table: dict, where: str):
    """The frame with each mapped contract column computed from its source expression (the
    source columns stay, as extra columns)."""
    import pandas as pd

    if not table:
        return df
    out = df.copy()
    for key, expr in table.items():
        expr = expr.strip()
        if expr in df.columns:
            out[key] = df[expr]
            continue
        try:
            value = df.eval(expr, engine="python")
        except pd.errors.UndefinedVariableError as e:
            m = re.search(r"name '(.+?)' is not defined", str(e))
            name = m.group(1) if m else str(e)
            dotted = [c for c in df.columns if str(c).startswith(name + ".") or " " in str(c)]
            hint = (f"; a name with dots or spaces goes in backticks, e.g. `{dotted[0]}`" if dotted else "")
            raise InputError(f"[csv] {key} = \"{expr}\" names the column '{name}', which {where} does not have; "
                             f"its columns: {', '.join(map(str, df.columns))}{hint}") from None
        except Exception as e:  # noqa: BLE001 - pandas' parser and evaluator raise many kinds
            raise InputError(f"[csv] {key} = \"{expr}\" is not an expression stid can evaluate "
                             f"({str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__}); write a "
                             "column name or arithmetic of columns, e.g. \"-imu_ax\" or \"time_ms * 0.001\"") from None
        if not isinstance(value, pd.Series):
            raise InputError(f"[csv] {key} = \"{expr}\" is a single number, not a column: name a source column")
        out[key] = value
    return out
