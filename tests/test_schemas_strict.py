"""Every JSON channel of a log declares every field it carries: the schemas are strict
(``additionalProperties: false`` in every object), and every message of real firmware logs
(both boards, one and four wheels, a car that restarted, a HELLO supplied from a vehicle
file with keys this stid does not know) validates against them."""

import json
import subprocess

import jsonschema
import pytest
from mcap.reader import make_reader

from conftest import tool
from host.mcap_log import SCHEMAS, McapLog
from host.mcap_read import read_log
from host.recorder import Recorder
from test_files_damage import T0_NS, circle_stream, hello_doc, record


def _objects(schema, path="$"):
    """Every object schema inside ``schema``, with where it is."""
    if isinstance(schema, dict):
        if schema.get("type") == "object":
            yield path, schema
        for k, v in schema.items():
            yield from _objects(v, f"{path}.{k}")
    elif isinstance(schema, list):
        for i, v in enumerate(schema):
            yield from _objects(v, f"{path}[{i}]")


def test_every_object_of_every_schema_is_closed():
    for name, schema in SCHEMAS.items():
        jsonschema.Draft7Validator.check_schema(schema)
        for path, obj in _objects(schema):
            if path.endswith(".unknown") or path.endswith(".frames") or path.endswith(".errors"):
                continue  # declared as open on purpose: keys unknown to this stid; counts by name
            assert obj.get("additionalProperties") is False, f"{name} {path} accepts undeclared fields"
            assert obj.get("properties"), f"{name} {path} declares no fields"


def _validate_all(path) -> dict:
    """Validate every JSON message of ``path`` against its channel's schema; counts per topic."""
    counts = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        validators = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.message_encoding != "json":
                continue
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft7Validator(json.loads(schema.data))
            errors = list(validators[schema.id].iter_errors(json.loads(msg.data)))
            assert not errors, f"{channel.topic}: {errors[0].message} at {list(errors[0].absolute_path)}"
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


@pytest.mark.parametrize("board,wheels", [("pico", False), ("esp32", True)])
def test_every_message_of_a_firmware_log_validates(tmp_path, board, wheels):
    out = tmp_path / "run.mcap"
    r = subprocess.run([tool("stid-sim"), "--fast", "-o", str(out), "--board", board, "--duration", "2",
                        "--still", "0.5", *(["--wheel-speeds"] if wheels else [])],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    counts = _validate_all(out)
    for topic in ("/stid/hello", "/stid/status", "/stid/stats", "/stid/events", "/stid/samples"):
        assert counts.get(topic), (topic, counts)
    hello = read_log(out).hello
    assert hello["board"] == board and "unknown" not in hello


def test_a_restart_and_a_supplied_hello_with_unknown_keys_validate_and_are_kept(tmp_path):
    # a car that restarted: two boots in one log (car_restarts in the stats)
    path = tmp_path / "restart.mcap"
    record(circle_stream(1.5) + circle_stream(1.5, boot_id="0ddba11a"), path)
    counts = _validate_all(path)
    assert counts["/stid/stats"] and read_log(path).stats["car_restarts"]
    # a HELLO taken from a vehicle file's [board] table, with keys no firmware sends
    path = tmp_path / "supplied.mcap"
    log = McapLog(path, fsync=False)
    rec = Recorder(log)
    doc = dict(hello_doc(), gyro_zero_note="measured on the bench", channels={
        "ax": None, "ay": {"part": "ADXL335", "out": "y", "bandwidth_hz": 50, "gain_trim": 1.01},
        "az": None, "yaw": {"part": "LISY300AL", "out": "z", "bandwidth_hz": 88}, "vbat": None})
    rec.supply_hello(doc, "car.toml [board]")
    rec.feed(circle_stream(1.0, hello_every_s=None), T0_NS)
    rec.finish(T0_NS + 2_000_000_000)
    log.close()
    _validate_all(path)
    hello = read_log(path).hello
    # a key at the top stays where it was; one inside a table is kept under its dotted path
    assert hello["gyro_zero_note"] == "measured on the bench"
    with open(path, "rb") as f:
        sent = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(topics=["/stid/hello"])]
    assert sent[0]["unknown"]["channels.ay.gain_trim"] == 1.01
