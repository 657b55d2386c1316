"""stid calibrate: sensor zeros from a stand-still run, steering from slow circles."""

import math
import shutil
import subprocess

import numpy as np
import pytest

from conftest import REPO, tool
from hil_sim.manoeuvres import Plan
from hil_sim.record import record
from hil_sim.run import SimConfig
from hil_sim.sensors import SensorParams
from stid.load import load_file
from stid.vehicle_file import load_vehicle


@pytest.mark.parametrize("board", ["pico", "esp32"])
def test_standstill_finds_the_gyro_zero_and_zeroes_the_accelerometer(tmp_path, board):
    # a gyro whose zero-rate output is 30 mV off the datasheet's 1.65 V (9 deg/s)
    cfg = SimConfig(plan=Plan(name="standstill", duration=4, still=0.0), seed=1, board=board,
                    sens=SensorParams(gyro_zero=1.68))
    record(cfg, tmp_path / "still.mcap")
    v = tmp_path / "car.toml"
    shutil.copy(REPO / "docs" / "examples" / "rc8.toml", v)
    r = subprocess.run([tool("stid"), "calibrate", str(tmp_path / "still.mcap"), "--vehicle", str(v)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    veh = load_vehicle(v)
    assert veh.sensors["gyro_zero_v"] == pytest.approx(1.68, abs=1e-3)
    assert (tmp_path / "car.toml.bak").exists() and "# The reference 1:8" in v.read_text()  # comments kept
    # calibrating again (routine) rewrites the table the first calibration wrote, multi-line arrays
    # and all: a table cut out by hand left the old accel_offset behind and broke the file
    with open(v, "a") as f:
        f.write("# my own note at the end\n")
    first = load_vehicle(v).sensors
    r = subprocess.run([tool("stid"), "calibrate", str(tmp_path / "still.mcap"), "--vehicle", str(v)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    again = load_vehicle(v)
    assert again.sensors.keys() == first.keys() and len(again.sensors["accel_offset"]) == 3
    assert again.sensors["gyro_zero_v"] == pytest.approx(first["gyro_zero_v"], abs=1e-6)
    assert again.mass == veh.mass and "# my own note at the end" in v.read_text()
    run = load_file(tmp_path / "still.mcap", veh)[0]
    assert abs(np.mean(run.ay)) < 0.02 and abs(np.mean(run.ax)) < 0.02
    if board == "esp32":
        assert abs(veh.sensors["mount_roll"]) < math.radians(0.5)
        assert np.nanmean(run.extra["az"]) == pytest.approx(9.81, abs=0.05)


def test_steering_calibration_from_two_slow_circles(tmp_path):
    paths = []
    for k, amp in enumerate((0.12, -0.10)):
        cfg = SimConfig(plan=Plan(name="steady_circle", duration=10, speed=1.5, speed_end=1.5, steer_amp=amp),
                        seed=k)
        record(cfg, tmp_path / f"c{k}.mcap")
        paths.append(str(tmp_path / f"c{k}.mcap"))
    record(SimConfig(plan=Plan(name="standstill", duration=3, still=0.0), seed=3), tmp_path / "still.mcap")
    v = tmp_path / "car.toml"
    v.write_text('name = "x"\nmass = 9.31\na = 0.2326\nb = 0.2874\n[steering]\ncenter_us = 1450.0\nus_per_rad = 1000.0\n')
    r = subprocess.run([tool("stid"), "calibrate", str(tmp_path / "still.mcap"), "--vehicle", str(v),
                        "--circle", paths[0], "--circle", paths[1]], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    veh = load_vehicle(v)
    assert veh.steer_center_us == pytest.approx(1500.0, abs=8.0)
    assert veh.steer_us_per_rad == pytest.approx(500.0 / math.radians(25.0), rel=0.03)


def test_calibrate_refuses_a_moving_car(tmp_path):
    record(SimConfig(plan=Plan(name="random_steer", duration=2, still=0.5, run_up=1), seed=1), tmp_path / "m.mcap")
    r = subprocess.run([tool("stid"), "calibrate", str(tmp_path / "m.mcap"), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "o.toml")],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "standing still" in r.stderr and "Traceback" not in r.stderr


def test_calibrate_names_an_unwritable_output_before_its_results(tmp_path):
    """It printed the whole calibration, then 'error: No such file or directory', exit 1."""
    r = subprocess.run([tool("stid"), "calibrate", str(tmp_path / "any.mcap"), "--vehicle",
                        str(REPO / "docs" / "examples" / "rc8.toml"), "-o", str(tmp_path / "nodir" / "c.toml")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "the directory" in r.stderr and "does not exist" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_csv_is_told_what_calibrate_takes_not_called_a_corrupted_mcap(tmp_path):
    csv = tmp_path / "still.csv"
    t = np.arange(1000) / 200.0
    csv.write_text("t,steer,ay,r,vx\n" + "\n".join(f"{x:.3f},0,0.01,0.002,0" for x in t) + "\n")
    r = subprocess.run([tool("stid"), "calibrate", str(csv), "--vehicle", str(REPO / "docs" / "examples" / "rc8.toml"),
                        "-o", str(tmp_path / "o.toml")], capture_output=True, text=True)
    assert r.returncode == 2 and "takes a stand-still logged by stid-log" in r.stderr, r.stderr
    assert "corrupted" not in r.stderr and not (tmp_path / "o.toml").exists()
