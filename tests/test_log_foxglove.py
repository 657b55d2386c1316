"""A log people can look at: one SI message per sample on the host clock, a complete
schema for every JSON channel, no integer JavaScript cannot hold."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from host.mcap_log import JSON_SAFE, SI_TOPIC
from host.mcap_read import read_log
from test_files_damage import RADIUS, RATE, V, circle_stream, record


@pytest.fixture(scope="module")
def circle_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("fox") / "run.mcap"
    # the first HELLO is lost on the link: samples before it must still reach the SI view
    stream = circle_stream(4.0, hello_every_s=1.0)
    first_hello_end = stream.index(b"\x00") + 1
    record(stream[first_hello_end:], path)
    return path


def _messages(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        out = [(schema, channel, msg) for schema, channel, msg in reader.iter_messages(log_time_order=False)]
    return summary, out


def _ints(doc):
    if isinstance(doc, bool):
        return
    if isinstance(doc, int):
        yield doc
    elif isinstance(doc, dict):
        for v in doc.values():
            yield from _ints(v)
    elif isinstance(doc, list):
        for v in doc:
            yield from _ints(v)


def test_every_json_message_matches_a_complete_schema(circle_log):
    summary, msgs = _messages(circle_log)
    for s in summary.schemas.values():
        assert s.encoding == "jsonschema"
        schema = json.loads(s.data)
        assert schema["type"] == "object" and schema["properties"], f"{s.name} has no properties"
        jsonschema.Draft7Validator.check_schema(schema)
    checked = 0
    validators = {}
    for schema, channel, msg in msgs:
        if channel.message_encoding != "json":
            continue
        doc = json.loads(msg.data)
        if schema.id not in validators:
            validators[schema.id] = jsonschema.Draft7Validator(json.loads(schema.data))
        validators[schema.id].validate(doc)
        big = [i for i in _ints(doc) if abs(i) >= JSON_SAFE]
        assert not big, f"{channel.topic}: integers beyond 2^53 {big[:3]}"
        checked += 1
    assert checked > 4 * RATE


def test_one_si_message_per_sample_on_the_host_clock(circle_log):
    log = read_log(circle_log)
    _, msgs = _messages(circle_log)
    si = [(m.log_time, json.loads(m.data)) for _, c, m in msgs if c.topic == SI_TOPIC]
    # every sample the file holds, once, including those before the first HELLO got through
    assert sorted(d["index"] for _, d in si) == log.samples["index"].tolist()
    si.sort(key=lambda x: x[1]["index"])
    ay = np.array([d["ay"] for _, d in si])
    r = np.array([d["r"] for _, d in si])
    one_count_ay = 10 * 9.81 / 4095  # [m/s^2]
    one_count_r = np.radians(3.3 / 4095 / 3.3e-3)  # [rad/s]
    assert np.all(np.abs(ay - V * V / RADIUS) <= one_count_ay)
    assert np.all(np.abs(r - V / RADIUS) <= one_count_r)
    assert all(d["az"] is None for _, d in si)  # not sampled: null, not a number
    t = np.array([d["t"] for _, d in si])
    assert np.allclose(np.diff(t), 1 / RATE)
    # log time: the sample's own instant on the host clock, spaced by the MCU's period
    log_t = np.array([lt for lt, _ in si], dtype=np.int64)
    assert np.allclose(np.diff(log_t), 1e9 / RATE, atol=5e3)
    assert np.all(log_t <= log.samples["t_host_ns"])  # never later than it was received


def test_wheel_rate_from_hall_edges_of_a_steady_wheel():
    """A wheel turning at 20 rad/s with one magnet: an edge every 2*pi/20 s; the view says
    20 rad/s from the second edge on, across reads of any size."""
    from host import protocol as p
    from host.si_view import SiView
    from test_files_damage import hello_doc

    omega, rate = 20.0, 500
    n = 2 * rate
    t_us = np.arange(n, dtype=np.int64) * (1_000_000 // rate)
    period_us = 2 * np.pi / omega * 1e6
    count = np.floor(t_us / period_us).astype(np.int64)
    edge_us = np.round(count * period_us).astype(np.int64)
    arr = np.zeros(n, p.DECODED_DTYPE)
    arr["t_us"], arr["wheel_count"], arr["wheel_t_us"] = t_us, count % 65536, edge_us
    view = SiView(hello_doc())
    out = np.concatenate([view.columns(arr[a:a + 37], t_us[a:a + 37])["wheel_rate"] for a in range(0, n, 37)])
    second_edge = np.searchsorted(t_us, 2 * period_us)
    assert np.all(np.isnan(out[:np.searchsorted(t_us, period_us)]))  # one edge: no rate yet
    assert np.allclose(out[second_edge + 1:], omega, rtol=1e-4)
