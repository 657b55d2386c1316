"""CSV files from other loggers: their delimiter, a [csv] map of their columns, and a
steering column in servo units, against the same drive as a contract CSV.

The drive is tests/ros_data.py's plain-physics car (not stid's model).
"""

import numpy as np
import pytest

import ros_data as rd
from stid.errors import InputError
from stid.load import load_file
from stid.vehicle_file import load_vehicle


@pytest.fixture(scope="module")
def drive():
    return rd.drive(duration=25.0)


@pytest.fixture(scope="module")
def contract(drive, tmp_path_factory):
    d = tmp_path_factory.mktemp("contract")
    (run,) = load_file(rd.contract_csv(drive, d / "c.csv"), load_vehicle(rd.vehicle_toml(d / "car.toml")))
    return run


def _columns(drive):
    return rd.contract_columns(drive)


def _write(path, cols, sep=",", decimal="."):
    names = list(cols)
    rows = [sep.join(names)]
    for row in np.column_stack([cols[n] for n in names]):
        rows.append(sep.join(f"{v:.9g}".replace(".", decimal) for v in row))
    path.write_text("\n".join(rows) + "\n")
    return path


def _vehicle(tmp_path, extra=""):
    return load_vehicle(rd.vehicle_toml(tmp_path / "car.toml", extra))


def _same(run, contract):
    for k in ("t", "steer", "ay", "r", "vx"):
        np.testing.assert_allclose(getattr(run, k), getattr(contract, k), rtol=1e-6, atol=1e-7, err_msg=k)


def test_semicolon_and_decimal_commas_are_read(drive, contract, tmp_path):
    path = _write(tmp_path / "excel.csv", _columns(drive), sep=";", decimal=",")
    (run,) = load_file(path, _vehicle(tmp_path))
    _same(run, contract)
    assert "read as ';'-separated, decimal commas" in run.meta["notes"]


def test_a_logger_s_own_columns_mapped_with_scale_and_sign(drive, contract, tmp_path):
    """Time in ms, an IMU turned (the car's y is its -x), a gyro in deg/s, speed in km/h, and
    ROS-style column names with dots (rostopic echo -p): all through [csv]."""
    c = _columns(drive)
    cols = {"time_ms": c["t"] * 1e3, "imu_ax": -c["ay"], "field.angular_velocity.z": np.degrees(c["r"]),
            "speed_kmh": c["vx"] * 3.6, "steer_rad": c["steer"], "battery_v": np.full(len(c["t"]), 7.4)}
    path = _write(tmp_path / "logger.csv", cols, sep="\t")
    table = ('[csv]\nt = "time_ms * 0.001"\nay = "-imu_ax"\nr = "`field.angular_velocity.z` * 0.017453292519943295"\n'
             'vx = "speed_kmh / 3.6"\nsteer = "steer_rad"\n')
    (run,) = load_file(path, _vehicle(tmp_path, table))
    _same(run, contract)
    assert "battery_v" in run.extra  # extra columns are kept (the contract), the sources among them


def test_unmapped_columns_say_how_the_file_was_read(drive, tmp_path):
    c = _columns(drive)
    path = _write(tmp_path / "own.csv", {"time": c["t"], "steer": c["steer"], "lat_acc": c["ay"], "yaw": c["r"],
                                         "speed": c["vx"]}, sep=";")
    with pytest.raises(InputError) as e:
        load_file(path, _vehicle(tmp_path))
    msg = str(e.value)
    assert "\n" not in msg
    assert "lacks the column(s) t, ay, r, vx; its columns (read as ';'-separated): time, steer, lat_acc, yaw, speed" in msg
    assert "[csv] table" in msg


def test_a_map_naming_a_missing_column_is_one_line(drive, tmp_path):
    c = _columns(drive)
    path = _write(tmp_path / "own.csv", dict(c, imu_ax=-c["ay"]))
    with pytest.raises(InputError) as e:
        load_file(path, _vehicle(tmp_path, '[csv]\nay = "-imu_ay"\n'))
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith('[csv] ay = "-imu_ay" names the column \'imu_ay\', which ')
    assert msg.endswith("does not have; its columns: t, steer, ay, r, vx, imu_ax")


def test_csv_table_keys_are_contract_columns(tmp_path):
    with pytest.raises(InputError, match=r"unknown column 'yaw' in \[csv\]"):
        _vehicle(tmp_path, '[csv]\nyaw = "gyro_z"\n')


def test_undelimited_file_is_named(tmp_path):
    path = tmp_path / "odd.csv"
    path.write_text("t;steer,ay\n1;2\n3,4,5\n")
    with pytest.raises(InputError, match="cannot tell how its columns are separated"):
        load_file(path, None)


# -- servo units ------------------------------------------------------------------------------

SERVO = {
    # the VESC's 0-1 command (f1tenth_system vesc.yaml: 0.15-0.85 around 0.5304)
    "0-1": (lambda a: rd.SERVO_GAIN * a + rd.SERVO_OFFSET, "a servo command in 0-1 units",
            f"[steering]\noffset = {rd.SERVO_OFFSET}\ngain = {rd.SERVO_GAIN}\n"),
    "0-1 negated": (lambda a: -(rd.SERVO_GAIN * a + rd.SERVO_OFFSET), "a negated servo command in 0-1 units",
                    f"[steering]\noffset = {-rd.SERVO_OFFSET}\ngain = {-rd.SERVO_GAIN}\n"),
    # a normalised +-1 stick, full lock 0.15 rad (reaches beyond any steering lock as radians)
    "+-1": (lambda a: np.clip(a / 0.15, -1, 1), "a servo command in +-1 units",
            "[steering]\noffset = 0.0\ngain = 6.666666666666667\n"),
    "pulse us": (lambda a: 1500.0 + 1145.9 * a, "a servo pulse width in us",
                 "[steering]\ncenter_us = 1500.0\nus_per_rad = 1145.9\n"),
    # a percent command (0-100, 50 straight ahead): it used to be told "degrees"
    "percent": (lambda a: 50.0 + 120.0 * a, "a servo command in units with an offset",
                "[steering]\noffset = 50.0\ngain = 120.0\n"),
}


@pytest.mark.parametrize("kind", list(SERVO))
def test_servo_units_are_refused_until_mapped(kind, drive, contract, tmp_path):
    to_servo, looks, table = SERVO[kind]
    c = _columns(drive)
    path = _write(tmp_path / "servo.csv", dict(c, steer=to_servo(c["steer"])))
    with pytest.raises(InputError) as e:
        load_file(path, _vehicle(tmp_path))
    msg = str(e.value)
    assert f"'steer' looks like {looks}" in msg and "\n  [steering]\n" in msg
    (run,) = load_file(path, _vehicle(tmp_path, table))
    if kind == "+-1":  # clipped at full lock: equal where it was not
        inside = np.abs(c["steer"]) < 0.15
        np.testing.assert_allclose(run.steer[inside], contract.steer[inside], atol=1e-7)
    else:
        _same(run, contract)


def test_servo_map_lines_as_given_load_the_run(drive, contract, tmp_path):
    """The lines the refusal gives are estimated from the run: added as they are, the steer is
    the road-wheel angle to within the estimate (the speed varied, so understeer is apart)."""
    c = _columns(drive)
    path = _write(tmp_path / "servo.csv", dict(c, steer=rd.SERVO_GAIN * c["steer"] + rd.SERVO_OFFSET))
    with pytest.raises(InputError) as e:
        load_file(path, _vehicle(tmp_path))
    block = str(e.value).split("\n  [steering]\n")[1]
    (run,) = load_file(path, _vehicle(tmp_path, "[steering]\n" + block.replace("  ", "") + "\n"))
    scale = np.polyfit(contract.steer, run.steer, 1)[0]
    assert scale == pytest.approx(1.0, abs=0.05)
