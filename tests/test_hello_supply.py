"""--hello-from: what can stand in for a HELLO that never got through. An earlier log of the
same board can (tests/test_log_port.py records one), and so can a vehicle file whose [board]
table declares the HELLO (test_log_port too); a vehicle file without one cannot (the car's
description holds no ADC scale, tick modulus or pin configuration), and saying so must
happen at once, in one line, before a run is recorded that it was meant to rescue."""

import subprocess

import pytest
from conftest import REPO, tool

from host.errors import HostError
from host.hello_supply import MCAP_MAGIC, check_source

VEHICLE = REPO / "docs" / "examples" / "rc8.toml"


def _one_error_line(err: str, prog: str) -> str:
    lines = [x for x in err.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error") and "Traceback" not in err, err
    return lines[0]


def test_stid_log_refuses_a_vehicle_file_before_recording(tmp_path):
    out = tmp_path / "run.mcap"
    # the port is never opened: the refusal comes first
    r = subprocess.run([tool("stid-log"), str(tmp_path / "no-such-port"), "-o", str(out), "--hello-from",
                        str(VEHICLE)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    line = _one_error_line(r.stderr, "stid-log")
    assert "vehicle file" in line and "EARLIER.mcap" in line and "ADC" in line
    assert not out.exists()


def test_stid_repair_refuses_a_vehicle_file_and_writes_nothing(tmp_path):
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(MCAP_MAGIC + b"\x00" * 64)
    fixed = tmp_path / "fixed.mcap"
    r = subprocess.run([tool("stid"), "repair", str(bare), "-o", str(fixed), "--hello-from", str(VEHICLE)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "vehicle file" in _one_error_line(r.stderr, "stid repair")
    assert not fixed.exists()


@pytest.mark.parametrize("content, says", [
    (None, "No such file"),
    (b"t,steer,ay\n0,0,0\n", "is not an MCAP log"),
    (b'mass = 9.3\na = 0.23\nb = 0.29\nname = "mine"\n', "is a vehicle file"),
])
def test_check_source_names_what_is_wrong(tmp_path, content, says):
    path = tmp_path / "donor"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(HostError) as e:
        check_source(path)
    assert says in str(e.value) and "\n" not in str(e.value)


def test_check_source_accepts_an_mcap_log(tmp_path):
    path = tmp_path / "earlier.mcap"
    path.write_bytes(MCAP_MAGIC + b"\x00" * 64)
    assert check_source(path) == path


def test_a_board_table_must_declare_what_conversion_needs(tmp_path):
    """A vehicle file's [board] stands in for a HELLO only when complete: the refusal names
    each missing key (here the ADC reference and the tick modulus)."""
    v = tmp_path / "car.toml"
    v.write_text('name = "mine"\nmass = 9.3\na = 0.23\nb = 0.29\n\n[board]\nproto = 3\nrate_hz = 500\n'
                 'adc = {bits = 12, unit = "count"}\n')
    with pytest.raises(HostError) as e:
        check_source(v)
    msg = str(e.value)
    assert "adc.vref" in msg and "mod (" in msg and "\n" not in msg


@pytest.mark.parametrize("line, says", [
    ('adc = {bits = 12, vref = 3.3, unit = "volts"}', "adc.unit"),
    ('adc = {bits = 12, vref = "3.3", unit = "count"}', "adc.vref"),
])
def test_a_board_table_with_values_no_board_sends_is_refused(tmp_path, line, says):
    v = tmp_path / "car.toml"
    v.write_text(f'name = "mine"\nmass = 9.3\na = 0.23\nb = 0.29\n\n[board]\nproto = 9\nrate_hz = 500\n'
                 f'mod = 1073741824\n{line}\n')
    with pytest.raises(HostError) as e:
        check_source(v)
    msg = str(e.value)
    assert says in msg and "proto = 9" in msg and "\n" not in msg
