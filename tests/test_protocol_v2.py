"""Protocol version 2: steer timing on the wire, four wheel speeds, channel bandwidths,
and version 1 logs that still load.

The expectations here are plain arithmetic on what the stimulus generated (pulse
rising edges and widths, hall edges) and on the truth, not the simulator's own
helpers, so a mistake there cannot hide in both."""

import json
import math
import struct
import zlib

import numpy as np
import pytest
from cobs import cobs

from hil_sim.manoeuvres import Plan
from hil_sim.record import firmware_bytes, record_stream, write_csv
from hil_sim.run import SimConfig, simulate_run
from host import protocol as p
from host import units
from host.frame_decoder import FrameDecoder
from host.mcap_log import McapLog
from host.mcap_read import read_log
from host.recorder import Recorder

MOD = 1 << 30
T0_NS = 1_700_000_000_000_000_000


# -- a version 1 log still loads ---------------------------------------------------

def _v1_wire(ftype, seq, t_us, body):
    raw = struct.pack("<BBII", 1, ftype, seq, t_us) + body
    return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"


def test_a_version_1_log_still_loads(tmp_path):
    """A file written from a protocol 1 car (22-byte records, HELLO with one `wheel`) loads:
    every v1 field as sent, steer time unknown, no extra wheels."""
    hello = {"proto": 1, "fw": "0.1.0", "board": "pico", "boot_id": "0badcafe", "rate_hz": 500, "batch": 10,
             "mod": MOD, "adc": {"bits": 12, "vref": 3.3, "unit": "count"}, "adc_clip_v": None,
             "channels": {"ax": {"pin": 26, "part": "ADXL335", "out": "ratiometric"}, "ay": None, "az": None,
                          "yaw": None, "vbat": None},
             "steer": {"pin": 2, "period_us": 20000, "timeout_us": 100000},
             "wheel": {"pin": 3, "pulses_per_rev": 1, "wheel": "rear"}}
    stream = _v1_wire(1, 0, 100, json.dumps(hello).encode())
    rows = []
    for f in range(30):  # 300 samples at 500 Hz; a hall edge every 25 ms (40 rev/s)
        body = struct.pack("<IB", 10 * f, 10)
        for i in range(10 * f, 10 * f + 10):
            t = 1000 + 2000 * i
            n_edges = t // 25_000
            row = (t, 2000 + i, 0xFFFF, 0xFFFF, 0xFFFF, 1500 + i % 7, n_edges, n_edges * 25_000, 0xFFFF)
            rows.append(row)
            body += struct.pack("<IHHHHHHIH", *row)
        stream += _v1_wire(2, f + 1, 1000 + 2000 * (10 * f + 9) + 50, body)
    log = McapLog(tmp_path / "v1.mcap", fsync=False)
    rec = Recorder(log)
    rec.feed(stream, T0_NS)
    rec.finish(T0_NS + 10**9)
    log.close()

    data = read_log(tmp_path / "v1.mcap")
    s = data.samples
    assert len(s) == 300 and data.hello["proto"] == 1
    v1_fields = ("t_us", "ax", "ay", "az", "yaw", "steer_us", "wheel_count", "wheel_t_us", "vbat")
    for k, name in enumerate(v1_fields):
        assert np.array_equal(s[name], [r[k] for r in rows]), name
    assert np.all(s["steer_t_us"] == 0xFFFFFFFF)  # unknown on protocol 1
    for k in (1, 2, 3):
        assert np.all(s[f"wheel{k}_count"] == 0xFFFF) and np.all(s[f"wheel{k}_t_us"] == 0xFFFFFFFF)
    # the one declared wheel: 40 rev/s = 251.3 rad/s once two edges are in
    w = units.wheel_speeds(s["t_mcu_us"], s, data.hello)
    assert list(w) == ["w_rear"]
    assert w["w_rear"][-1] == pytest.approx(2 * math.pi * 40, rel=1e-9)


def test_v1_and_v2_frames_in_one_stream_decode_together():
    """A car reflashed mid-log: v1 then v2 frames, each by its own layout."""
    def v2_wire(seq, body):
        raw = struct.pack("<BBII", 2, 2, seq, 0) + body
        return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"

    v1 = _v1_wire(2, 0, 0, struct.pack("<IB", 0, 1) + struct.pack("<IHHHHHHIH", 5, 1, 2, 3, 4, 1500, 9, 4, 7))
    v2 = v2_wire(1, struct.pack("<IB", 1, 1) + struct.pack("<IHHHHHHIHI", 6, 1, 2, 3, 4, 1600, 9, 4, 7, 3))
    frames = FrameDecoder().feed(v1 + v2)
    arr = p.samples_from_records((f.version, f.type, f.samples_bytes()) for f in frames)
    assert arr["steer_us"].tolist() == [1500, 1600]
    assert arr["steer_t_us"].tolist() == [0xFFFFFFFF, 3]


# -- steer time on the wire, and a receiver clock that is not locked to the sampler --

@pytest.fixture(scope="module")
def steer_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("steer")
    start = MOD - 2_000_000  # the ticks wrap 2 s into the run
    cfg = SimConfig(plan=Plan(name="random_steer", duration=8, still=1, run_up=1), seed=11, start_ticks=start)
    run = simulate_run(cfg)
    record_stream(firmware_bytes(run), tmp / "run.mcap", T0_NS)
    return cfg, run, read_log(tmp / "run.mcap")


def test_steer_t_us_is_the_falling_edge_of_the_pulse_whose_width_is_sent(steer_run):
    cfg, run, log = steer_run
    s = log.samples
    rise = np.asarray(run.stimulus.steer_rise_us, dtype=np.int64)
    width = np.asarray(run.stimulus.steer_us, dtype=np.int64)
    fall = rise + width  # virtual us since the start
    t = s["t_mcu_us"] - cfg.start_ticks  # virtual sample times
    # the latest pulse that ended before the sample (an edge in the sample's own
    # microsecond comes after it: the board fires the timer first)
    k = np.searchsorted(fall, t, side="left") - 1
    have = k >= 0
    assert have.sum() > 0.9 * len(s)
    assert np.array_equal(s["steer_t_us"][have].astype(np.int64), (fall[k[have]] + cfg.start_ticks) % MOD)
    assert np.array_equal(s["steer_us"][have].astype(np.int64), width[k[have]])
    assert np.all(s["steer_t_us"] < MOD)


def test_pulse_edges_sweep_through_the_sample_period(steer_run):
    cfg, run, log = steer_run
    s = log.samples
    rise = np.asarray(run.stimulus.steer_rise_us, dtype=np.int64)
    fall = rise + np.asarray(run.stimulus.steer_us, dtype=np.int64)
    period = np.diff(rise)
    assert np.all(period % 2000 != 0) or np.std(period) > 0  # not a multiple of the sample period
    assert abs(np.median(period) - 20000) > 1  # a receiver clock of its own (ppm off nominal)
    # phase of each falling edge within the sample period, seen from the samples themselves
    t = s["t_mcu_us"] - cfg.start_ticks
    k = np.searchsorted(t, fall[(fall > t[0]) & (fall < t[-1])], side="left")
    lag = t[k] - fall[(fall > t[0]) & (fall < t[-1])]  # edge -> next sample [us], 0..2000
    assert lag.min() >= 0 and lag.max() <= 2000
    hist, _ = np.histogram(lag, bins=10, range=(0, 2000))
    assert np.all(hist >= 0.3 * len(lag) / 10), hist  # every tenth of the period is visited
    # the average steer timing error a sample-time stamp would make is ~1 ms, not a constant
    assert 700 < lag.mean() < 1300


def test_truth_takes_each_command_at_its_falling_edge():
    """ay follows the front road-wheel angle without lag (Fyf = Cf (delta - ...)), so the
    truth's ay jumps by Cf * d_delta * cos(delta) / m exactly at the falling edge of the
    first pulse that carries the new width: not a microsecond before or after."""
    from hil_sim import vehicle

    car = vehicle.CarParams()
    dt = 1e-3
    t = np.arange(0, 2.0, dt)
    plan = np.where(t >= 1.0, 0.05, 0.0)
    tr = vehicle.simulate(car, vehicle.Effects(set()), t, plan, np.full(len(t), 4.0),
                          pulse_rise_us=3000 + np.arange(120) * 20_006 + (np.arange(120) * 37) % 5)
    k = int(np.flatnonzero(tr.steer_pulses_us != 1500)[0])
    t_fall = (tr.steer_rise_us[k] + tr.steer_pulses_us[k]) * 1e-6
    assert t_fall % dt > 1e-6  # the edge falls inside an integration step
    d_new = (tr.steer_pulses_us[k] - car.steer_center_us) / car.steer_us_per_rad
    tg = t_fall + np.array([-3e-6, -1.5e-6, -0.5e-6, 0.5e-6, 1.5e-6, 3e-6])
    ay = tr.dense(tg)["ay"]
    jump = car.Cf * d_new * math.cos(d_new) / car.mass
    assert ay[3] - ay[2] == pytest.approx(jump, rel=0.02)
    assert abs(ay[1] - ay[0]) < 0.01 * jump and abs(ay[2] - ay[1]) < 0.01 * jump
    assert abs(ay[4] - ay[3]) < 0.01 * jump and abs(ay[5] - ay[4]) < 0.01 * jump
    # the grid's command is the old one before the edge's step ends, the new one after
    i = int(t_fall // dt)
    assert tr.delta_cmd[i] == 0.0 and tr.delta_cmd[i + 1] == pytest.approx(d_new)


# -- four wheel speeds ------------------------------------------------------------------

@pytest.fixture(scope="module")
def four_wheel_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("four")
    cfg = SimConfig(plan=Plan(name="random_steer", duration=6, still=1, run_up=2, steer_amp=math.radians(5)),
                    seed=4, wheel_speeds=True, board="esp32")
    run = simulate_run(cfg)
    stream = firmware_bytes(run)
    record_stream(stream, tmp / "run.mcap", T0_NS)
    write_csv(run, stream, tmp / "run.csv")
    return cfg, run, read_log(tmp / "run.mcap"), tmp / "run.csv"


def test_four_wheel_frames_and_hello(four_wheel_run):
    cfg, run, log, _ = four_wheel_run
    wheels = log.hello["wheels"]
    assert [w["wheel"] for w in wheels] == ["fl", "fr", "rl", "rr"]
    assert log.hello["wheel"] == wheels[0] and log.hello["proto"] == p.VERSION  # the firmware sends the newest
    s = log.samples
    # every hall count is the number of that wheel's edges before the sample, edge times exact
    # where pin interrupts are hard (the Pico). On the ESP32 a pin callback is scheduled
    # (ports/esp32/machine_pin.c): an edge is counted and timed when its callback runs, after
    # any blocking write, so a count is never ahead and at most one behind, and an edge time
    # is never early and late by at most the longest write (the full HELLO: its bytes beyond
    # the UART's 128-byte buffer at 921600 baud)
    t = s["t_mcu_us"] - cfg.start_ticks
    longest_write_us = (len(json.dumps(log.hello)) + 20 - 128) * 10_000_000 // 921_600
    for (cnt, tf), w in zip(p.WHEEL_FIELDS, wheels):
        pin, edges = run.stimulus.wheel_halls[w["wheel"]]
        assert pin == w["pin"]
        edges = np.asarray(edges, np.int64)
        # a scheduled (ESP32) sample runs after every interrupt of its microsecond
        n = np.searchsorted(edges, t, side="left" if log.hello["timer"] == "hard" else "right")
        got = s[cnt].astype(np.int64)
        seen = got > 0
        t_edge = s[tf][seen].astype(np.int64)
        if log.hello["board"] == "pico":
            assert np.array_equal(got, n % 65536), w
            assert np.array_equal(t_edge, edges[n[seen] - 1] % MOD)
            continue
        assert np.all((n - got >= 0) & (n - got <= 1)), w
        late = (t_edge - edges[got[seen] - 1]) % MOD
        assert late.max() <= longest_write_us, (w, late.max())


def test_four_wheel_speeds_match_the_truth(four_wheel_run):
    cfg, run, log, csv_path = four_wheel_run
    s = log.samples
    w = units.wheel_speeds(s["t_mcu_us"], s, log.hello, centred=True)  # as stid's loader computes them
    assert sorted(w) == ["w_fl", "w_fr", "w_rl", "w_rr"]
    tv = (s["t_mcu_us"] - cfg.start_ticks) * 1e-6
    tr, car = run.traj, cfg.car
    # the truth, from first principles: a wheel at the side offset +-track/2 rolls at
    # (vx -+ r track/2) / R; the driven rears turn faster by the slip Fx / Cx
    slip = tr.Fx / car.Cx
    truth = {"w_fl": (tr.vx - tr.r * car.track / 2) / car.wheel_radius,
             "w_fr": (tr.vx + tr.r * car.track / 2) / car.wheel_radius,
             "w_rl": (tr.vx - tr.r * car.track / 2) * (1 + slip) / car.wheel_radius,
             "w_rr": (tr.vx + tr.r * car.track / 2) * (1 + slip) / car.wheel_radius}
    moving = tv > cfg.plan.still + cfg.plan.run_up  # past the run-up: the speed estimate has settled
    assert moving.sum() > 1000
    for name, want in truth.items():
        wt = np.interp(tv, tr.t, want)
        err = (w[name][moving] - wt[moving]) / wt[moving]
        # one magnet per wheel: each value is the mean over an edge interval (~70 ms), at its middle
        assert np.median(np.abs(err)) < 0.01, name
        assert np.sqrt(np.mean(err ** 2)) < 0.02, name
        assert np.percentile(np.abs(err), 99) < 0.05, name
    # left and right differ as the yaw rate says (the steer is 5 deg rms): the four are not copies
    assert np.std(w["w_fr"][moving] - w["w_fl"][moving]) > 0.5
    # the CSV holds what the halls gave (what an ideal logger computes), not the truth
    import csv

    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    # ... at every sample whose values are all known: a wheel's speed before its first hall
    # interval is not known, and such a row is left out, never written as a number
    known = np.all([np.isfinite(w[name]) for name in truth], axis=0)
    assert len(rows) == int(known.sum()) and known.mean() > 0.95
    for name in truth:
        col = np.array([float(r[name]) for r in rows])
        assert np.allclose(col, w[name][known], rtol=1e-5, atol=1e-4), name


# -- HELLO --------------------------------------------------------------------------------

def test_hello_declares_channel_bandwidths_and_fits_one_frame(four_wheel_run):
    cfg, run, log, _ = four_wheel_run
    ch = log.hello["channels"]
    # ADXL335: f = 5 uF / C_out with the board's 0.1 uF capacitors; LISY300AL: 88 Hz internal
    assert ch["ax"]["bandwidth_hz"] == ch["ay"]["bandwidth_hz"] == ch["az"]["bandwidth_hz"] == 5.0 / 0.1
    assert ch["yaw"]["bandwidth_hz"] == 88
    assert ch["vbat"]["bandwidth_hz"] is None
    # the simulated sensors are filtered at what the board declares
    assert cfg.sens.acc_bandwidth == ch["ax"]["bandwidth_hz"] and cfg.sens.gyro_bandwidth == ch["yaw"]["bandwidth_hz"]
    # the largest full HELLO (ESP32, four wheels; as sent: without the keys the host adds) fits
    # one frame with room; on a lossy link the ~80-byte compact HELLO (every second) carries it
    sent = {k: v for k, v in log.hello.items() if k not in ("hello", "wheel")}
    size = p.HEADER_SIZE + len(json.dumps(sent, separators=(",", ":"))) + p.CRC_SIZE
    # room for what can still grow: an 8-byte uid (the Pico's: 4 hex digits more than the
    # ESP32's 6 bytes) and two-digit version parts (fw, micropython: 4 more); the firmware
    # refuses a HELLO over MAX_FRAME - 14 (app.py start)
    assert size + 4 + 4 <= p.MAX_FRAME - 14, size
