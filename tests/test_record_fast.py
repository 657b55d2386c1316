"""Firmware-in-the-loop recording, faster than real time: the samples in the MCAP
file are exactly the ADC counts the simulated sensors produced, in order."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from hil_sim.manoeuvres import Plan
from hil_sim.record import firmware_bytes, record_stream
from hil_sim.run import SimConfig, simulate_run
from host import protocol as p
from host.mcap_read import read_log


def record_run(run, path, start_ns=1_700_000_000_000_000_000):
    return record_stream(firmware_bytes(run), path, start_ns)


def expected_counts(run, t_virtual_us, pin, board):
    st = run.stimulus
    # the voltage at the sample's instant, interpolated between stimulus rows as the board's
    # ADC sees it (integer arithmetic in 1e-6 of 0.1 mV, rounded once by the converter,
    # exactly as the simulated board does)
    a = np.asarray(t_virtual_us, np.int64) * st.fs_sig
    row = a // 1_000_000
    vc = st.volts_counts(pin).astype(np.int64)  # 0.1 mV
    last = row >= st.n_rows - 1
    r0 = np.minimum(row, st.n_rows - 1)
    r1 = np.minimum(row + 1, st.n_rows - 1)
    v = np.where(last, vc[r0] * 1_000_000, vc[r0] * 1_000_000 + (vc[r1] - vc[r0]) * (a % 1_000_000))
    if board == "pico":
        return np.minimum((v * 4095 + 16_500_000_000) // 33_000_000_000, 4095)
    return (np.clip((v + 5000) // 10000, 150_000, 2_450_000) + 500) // 1000  # uV, then the firmware's mV


@pytest.mark.parametrize("board", ["pico", "esp32"])
def test_counts_exact_and_in_order(tmp_path, board):
    start = (1 << 30) - 3_000_000 if board == "pico" else 0  # pico: ticks wrap 3 s into the run
    cfg = SimConfig(plan=Plan(name="chirp", duration=4, still=1, run_up=2, steer_amp=0.06), seed=5,
                    board=board, start_ticks=start)
    run = simulate_run(cfg)
    stats = record_run(run, tmp_path / "run.mcap")
    log = read_log(tmp_path / "run.mcap")
    s = log.samples
    t_virtual = s["t_mcu_us"] - start  # unwrapped across the 2^30 wrap
    period = 1_000_000 // cfg.rate_hz
    armed = 0  # when the timer started: at once on the Pico (a sample stamps its scan, 16 us early)
    if board == "esp32":  # after the pulse counter's 2 ms self-test; each sample at or after its tick
        armed = int((t_virtual - (s["index"] + 1) * period).min())
        assert 2000 <= armed <= 3000
    n_expected = int((run.stimulus.duration_us - armed) * cfg.rate_hz // 1_000_000)
    assert len(s) == n_expected == stats["samples"]
    assert np.array_equal(s["index"], np.arange(len(s)))
    if log.hello["timer"] == "hard":
        assert np.array_equal(np.diff(t_virtual), np.full(len(s) - 1, period))
    else:  # ESP32: the callback is scheduled, late by up to a frame write, never early or lost here
        late = t_virtual - armed - (s["index"] + 1) * period
        assert late.min() == 0 and late.max() <= max(st["late_max_us"] for _, st in log.status)
    from hil_sim.run import WIRING

    wiring = WIRING[board]
    # the RP2040's DMA scan converts the channels one after another, 2 us apart at 500 Hz
    # (firmware/README.md: ax 0, ay +2, yaw +4 us after the record's instant)
    skew = {"ax": 0, "ay": 2, "yaw": 4} if (log.hello.get("capture") or {}).get("adc") == "dma" else {}
    for ch in ("ax", "ay", "yaw"):
        assert np.array_equal(s[ch], expected_counts(run, t_virtual + skew.get(ch, 0), wiring[ch], board)), ch
    if board == "pico":
        assert np.all(s["az"] == p.MISSING) and np.all(s["vbat"] == p.MISSING)
    else:
        assert np.array_equal(s["az"], expected_counts(run, t_virtual, wiring["az"], board))
    # servo pulses: the width of the latest complete pulse, as commanded (the ESP32's pulse
    # counter counts a 1 MHz clock over a pulse whose edges fall between its ticks: +-1 us)
    widths = np.unique(run.traj.steer_pulses_us)
    seen = np.unique(s["steer_us"][s["steer_us"] > 0]).astype(np.int64)
    off = np.abs(seen[:, None] - widths[None, :]).min(axis=1)
    assert off.max() <= (1 if (log.hello.get("capture") or {}).get("servo") == "pcnt" else 0)
    # hall pulses: the count at each sample is the number of edges before it (an edge in the
    # same microsecond as the timer comes after the sample: the board fires the timer first)
    # (a scheduled ESP32 sample runs after every interrupt of its microsecond: "right")
    edges = run.stimulus.hall_t_us
    side = "left" if log.hello["timer"] == "hard" else "right"
    assert np.array_equal(s["wheel_count"], np.searchsorted(edges, t_virtual, side=side) % 65536)
    assert stats["lost_frames"] == 0 and sum(stats["errors"].values()) == 0


def test_mcu_overrun_is_counted_not_hidden(tmp_path):
    cfg = SimConfig(plan=Plan(name="random_steer", duration=4, still=1, run_up=1), seed=2,
                    stalls=((3.0, 1.5),), ring_size=128)
    run = simulate_run(cfg)
    stats = record_run(run, tmp_path / "run.mcap")
    # 1.5 s stalled at 500 Hz = 750 samples, the ring holds 128: ~620 dropped on the car
    assert 550 < stats["mcu_overruns"] < 700
    assert stats["missing_samples"] == stats["mcu_overruns"]
    assert stats["lost_frames"] == 0
    log = read_log(tmp_path / "run.mcap")
    assert np.all(np.diff(log.samples["index"]) >= 1)
    assert log.status[-1][1]["overruns"] == stats["mcu_overruns"]


def test_file_opens_in_the_official_mcap_reader(tmp_path):
    cfg = SimConfig(plan=Plan(name="step_steer", duration=2, still=1, run_up=1), seed=1)
    record_run(simulate_run(cfg), tmp_path / "run.mcap")
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic for c in summary.channels.values()}
        assert {"/stid/raw", "/stid/frames", "/stid/samples", "/stid/status", "/stid/hello",
                "/stid/stats"} <= topics
        schemas = {s.name: s for s in summary.schemas.values()}
        assert schemas["stid.Sample"].encoding == "jsonschema"
        n = 0
        for schema, channel, msg in reader.iter_messages(topics=["/stid/samples"]):
            doc = json.loads(msg.data)  # one sample per message, in SI units
            assert isinstance(doc["ay"], float) and isinstance(doc["index"], int)
            n += 1
        assert n == len(read_log(tmp_path / "run.mcap").samples)
        names = {m.name for m in reader.iter_metadata()}
        assert {"stid.hello", "stid.stats", "stid.clock"} <= names
        # the real firmware's HELLO, STATUS and the logger's events and stats fit their schemas
        import jsonschema

        validators = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.message_encoding == "json":
                if schema.id not in validators:
                    validators[schema.id] = jsonschema.Draft7Validator(json.loads(schema.data))
                validators[schema.id].validate(json.loads(msg.data))
        assert len(validators) == 5


def test_clock_model_recovers_offset_and_no_drift(tmp_path):
    cfg = SimConfig(plan=Plan(name="random_steer", duration=6, still=1, run_up=1), seed=3)
    record_run(simulate_run(cfg), tmp_path / "run.mcap", start_ns=1_700_000_000_000_000_000)
    clock = read_log(tmp_path / "run.mcap").metadata["stid.clock"]
    (fit,) = clock.values()
    assert abs(fit["drift_ppm"]) < 1.0
    # host = start + mcu time + 2 ms latency; the frame is sent after its last sample
    assert fit["offset_us"] == pytest.approx(1_700_000_000_000_000 + 2000, abs=25_000)
