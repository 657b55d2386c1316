"""Regenerate the golden vectors of the stid wire protocol (PROTOCOL.md).

The vectors are built with the third-party ``cobs`` package and ``zlib`` only —
deliberately not with any stid code — so that an error in our encoders or
decoders cannot leak into the reference they are tested against.

    python firmware/vectors/make_vectors.py      # rewrites vectors.json and vectors.txt

``vectors.json`` is read by the Python and MicroPython tests; ``vectors.txt`` is
the same content in a line format the C test reads without a JSON parser.

Every case names the protocol version its frames carry. Version 3 is what the
firmware sends; the version 1 and 2 cases stay so that every decoder keeps reading
old streams and logs (PROTOCOL.md, "Versions").
"""

import json
import struct
import zlib
from pathlib import Path

from cobs import cobs

HERE = Path(__file__).resolve().parent
MOD = 1 << 30
VERSION = 3
HELLO, SAMPLES, STATUS, SAMPLES4, HELLO_COMPACT = 1, 2, 3, 4, 5
SAMPLE_FIELDS_V1 = ("t_us", "ax", "ay", "az", "yaw", "steer_us", "wheel_count", "wheel_t_us", "vbat")
SAMPLE_FMT_V1 = "<IHHHHHHIH"
SAMPLE_FIELDS = SAMPLE_FIELDS_V1 + ("steer_t_us",)  # version 2, SAMPLES: 26 bytes
SAMPLE_FMT = SAMPLE_FMT_V1 + "I"
WHEELS3_FIELDS = ("wheel1_count", "wheel1_t_us", "wheel2_count", "wheel2_t_us", "wheel3_count", "wheel3_t_us")
WHEELS3_FMT = "<HIHIHI"  # appended in version 2 SAMPLES4 records: 44 bytes
STATUS_FIELDS_V2 = ("uptime_ms", "samples", "overruns", "frames", "tx_short",
                    "isr_max_us", "isr_last_us", "ring_peak", "ring_size")
STATUS_FMT_V2 = "<IIIIIHHHH"
STATUS_FIELDS = STATUS_FIELDS_V2 + ("missed", "late_max_us")  # version 3: 34 bytes
STATUS_FMT = STATUS_FMT_V2 + "IH"


def frame_bytes(ftype, seq, t_us, body, version=VERSION):
    raw = struct.pack("<BBII", version, ftype, seq, t_us) + body
    return raw + struct.pack("<I", zlib.crc32(raw))


def wire(frame):
    return cobs.encode(frame) + b"\x00"


def samples_body(index, samples, version=VERSION, four=False):
    body = struct.pack("<IB", index, len(samples))
    for s in samples:
        if version == 1:
            body += struct.pack(SAMPLE_FMT_V1, *(s[k] for k in SAMPLE_FIELDS_V1))
            continue
        body += struct.pack(SAMPLE_FMT, *(s[k] for k in SAMPLE_FIELDS))
        if four:
            body += struct.pack(WHEELS3_FMT, *(s[k] for k in WHEELS3_FIELDS))
    return body


def status_body(st, version=VERSION):
    if version < 3:
        return struct.pack(STATUS_FMT_V2, *(st[k] for k in STATUS_FIELDS_V2))
    return struct.pack(STATUS_FMT, *(st[k] for k in STATUS_FIELDS))


def compact_hello_body(uid):
    """The compact HELLO of HELLO_DOC3, packed field by field from PROTOCOL.md's table."""
    body = struct.pack("<I", 0x9F3A51C2)  # boot_id
    body += bytes([1, 1])  # board pico; flags: bit 0 hard timer, bit 1 simulated (no)
    body += struct.pack("<HB", 500, 10)  # rate_hz, batch
    body += bytes([0, 3, 0, 1, 26, 0])  # fw 0.3.0, MicroPython 1.26.0
    body += bytes([3, 12, 0])  # reset cause watchdog, adc bits 12, unit count
    body += struct.pack("<HH", 3300, 0)  # vref mV, clip mV (0: none)
    for part, bw in ((1, 50), (1, 50), (0, 0), (2, 88), (0, 0)):  # ax ay az yaw vbat
        body += struct.pack("<BH", part, bw)
    body += struct.pack("<HI", 20000, 100000)  # steer period, timeout
    body += bytes([1, 4, 0, 1, 2, 3])  # ppr, four wheels: fl fr rl rr
    body += struct.pack("<BIH", 1, 0, 2810)  # link usb, no baud, 28.10 bytes per sample
    body += bytes([len(uid)]) + uid
    return body


def sample(i, t0=1000, dt=2000, version=VERSION, four=False):
    s = {"t_us": (t0 + i * dt) % MOD, "ax": 2048 + i, "ay": 1900 - 7 * i, "az": 0xFFFF,
         "yaw": 2047 + 3 * i, "steer_us": 1500 + i, "wheel_count": (65530 + i) % 65536,
         "wheel_t_us": (t0 + i * dt - 300) % MOD, "vbat": 0xFFFF}
    if version >= 2:
        s["steer_t_us"] = (t0 + i * dt - 20000 + 7 * i) % MOD  # falling edge of the pulse, before t_us
    if four:
        for k in (1, 2, 3):
            s[f"wheel{k}_count"] = (100 * k + i) % 65536
            s[f"wheel{k}_t_us"] = (t0 + i * dt - 100 * k) % MOD
    return s


HELLO_DOC_V1 = {
    "proto": 1, "fw": "0.1.0", "board": "pico", "boot_id": "9f3a51c2", "rate_hz": 500,
    "batch": 10, "mod": MOD,
    "adc": {"bits": 12, "vref": 3.3, "unit": "count"}, "adc_clip_v": None,
    "channels": {
        "ax": {"pin": 26, "part": "ADXL335", "out": "ratiometric"},
        "ay": {"pin": 27, "part": "ADXL335", "out": "ratiometric"},
        "az": None,
        "yaw": {"pin": 28, "part": "LISY300AL", "out": "absolute"},
        "vbat": None,
    },
    "steer": {"pin": 2, "period_us": 20000, "timeout_us": 100000},
    "wheel": {"pin": 3, "pulses_per_rev": 1, "wheel": "rear"},
}

_WHEELS4 = [{"pin": 4, "pulses_per_rev": 1, "wheel": "fl"}, {"pin": 5, "pulses_per_rev": 1, "wheel": "fr"},
            {"pin": 3, "pulses_per_rev": 1, "wheel": "rl"}, {"pin": 6, "pulses_per_rev": 1, "wheel": "rr"}]
HELLO_DOC = {
    "proto": 2, "fw": "0.2.0", "board": "pico", "boot_id": "9f3a51c2", "rate_hz": 500,
    "batch": 10, "mod": MOD,
    "adc": {"bits": 12, "vref": 3.3, "unit": "count"}, "adc_clip_v": None,
    "channels": {
        "ax": {"pin": 26, "part": "ADXL335", "out": "ratiometric", "bandwidth_hz": 50},
        "ay": {"pin": 27, "part": "ADXL335", "out": "ratiometric", "bandwidth_hz": 50},
        "az": None,
        "yaw": {"pin": 28, "part": "LISY300AL", "out": "absolute", "bandwidth_hz": 88},
        "vbat": None,
    },
    "steer": {"pin": 2, "period_us": 20000, "timeout_us": 100000},
    "wheel": _WHEELS4[0], "wheels": _WHEELS4,
}
HELLO_DOC3 = dict({k: v for k, v in HELLO_DOC.items() if k != "wheel"}, proto=3, fw="0.3.0",
                  uid="e66038b7133a2b2f", micropython="1.26.0", timer="hard", reset_cause="watchdog",
                  link={"kind": "usb", "baud": None, "bytes_per_sample": 28.1})  # `wheel` dropped in 3
# what a receiver makes of the compact form: HELLO_DOC3 without the pins
HELLO_COMPACT_DECODED = {
    **{k: v for k, v in HELLO_DOC3.items() if k not in ("channels", "steer", "wheels")},
    "channels": {k: (None if v is None else {kk: vv for kk, vv in v.items() if kk != "pin"})
                 for k, v in HELLO_DOC["channels"].items()},
    "steer": {"period_us": 20000, "timeout_us": 100000},
    "wheel": {"pulses_per_rev": 1, "wheel": "fl"},
    "wheels": [{"pulses_per_rev": 1, "wheel": w} for w in ("fl", "fr", "rl", "rr")],
    "sim": False,
}


def frame_entry(ftype, seq, t_us, body, decoded):
    return {"type": ftype, "seq": seq, "t_us": t_us, "body": body.hex(), "decoded": decoded}


def build_cases():
    cases = []

    def ok(name, entries, note="", version=VERSION):
        stream = b"".join(wire(frame_bytes(e["type"], e["seq"], e["t_us"], bytes.fromhex(e["body"]), version))
                          for e in entries)
        cases.append({"name": name, "version": version, "note": note, "wire": stream.hex(), "frames": entries,
                      "errors": {}, "encode": True})

    st = {"uptime_ms": 61000, "samples": 30500, "overruns": 3, "frames": 3111, "tx_short": 1,
          "isr_max_us": 95, "isr_last_us": 41, "ring_peak": 37, "ring_size": 256}
    st3 = dict(st, missed=17, late_max_us=4321)
    sw = [{"t_us": MOD - 1, "ax": 0, "ay": 0xFFFF, "az": 0x0100, "yaw": 0x00FF, "steer_us": 0,
           "wheel_count": 0, "wheel_t_us": MOD - 2, "vbat": 0, "steer_t_us": 0}]
    s1 = [sample(0)]
    s10 = [sample(i) for i in range(10)]
    s4 = [sample(i, four=True) for i in range(3)]

    # Version 3 (sent today) and version 2 (old firmware, old logs): the same record
    # layouts; version 3 lengthens STATUS and adds the compact HELLO.
    for v in (3, 2):
        pre = "" if v == VERSION else f"v{v}_"
        doc = HELLO_DOC3 if v == 3 else HELLO_DOC
        hello_body = json.dumps(doc, separators=(",", ":")).encode()
        ok(pre + "hello", [frame_entry(HELLO, 0, 12345, hello_body, doc)], "four wheels, channel bandwidths",
           version=v)
        ok(pre + "samples_1", [frame_entry(SAMPLES, 1, 2100, samples_body(0, s1), {"index": 0, "samples": s1})],
           version=v)
        ok(pre + "samples_10", [frame_entry(SAMPLES, 2, 21000, samples_body(10, s10),
                                            {"index": 10, "samples": s10})], version=v)
        # Values just below the 2^30 wrap, and zero bytes everywhere COBS must stuff them.
        ok(pre + "samples_wrap_zeros", [frame_entry(SAMPLES, MOD - 1, MOD - 1, samples_body(MOD - 1, sw),
                                                    {"index": MOD - 1, "samples": sw})],
           "counters at 2^30 - 1 and many zero bytes", version=v)
        stv = st3 if v == 3 else st
        ok(pre + "status", [frame_entry(STATUS, 7, 99000, status_body(stv, v), stv)], version=v)
        # Longest legal SAMPLES frame: 38 samples, 1007 bytes.
        s38 = [sample(i, t0=5, dt=1000) for i in range(38)]
        ok(pre + "samples_38", [frame_entry(SAMPLES, 8, 42000, samples_body(400, s38),
                                            {"index": 400, "samples": s38})],
           "longest legal SAMPLES frame (1007 bytes)", version=v)
        ok(pre + "samples4_3", [frame_entry(SAMPLES4, 9, 43000, samples_body(500, s4, four=True),
                                            {"index": 500, "samples": s4})], "four hall sensors", version=v)
        s4w = [dict(sw[0], wheel1_count=0, wheel1_t_us=MOD - 1, wheel2_count=0xFFFF, wheel2_t_us=0,
                    wheel3_count=0x0100, wheel3_t_us=0x00FF0000)]
        ok(pre + "samples4_wrap_zeros", [frame_entry(SAMPLES4, 10, 5, samples_body(MOD - 1, s4w, four=True),
                                                     {"index": MOD - 1, "samples": s4w})],
           "four wheels, zero bytes", version=v)
        s22 = [sample(i, t0=5, dt=1000, four=True) for i in range(22)]
        ok(pre + "samples4_22", [frame_entry(SAMPLES4, 11, 44000, samples_body(600, s22, four=True),
                                             {"index": 600, "samples": s22})], "longest legal SAMPLES4 frame",
           version=v)
    uid = bytes.fromhex("e66038b7133a2b2f")
    ok("hello_compact", [frame_entry(HELLO_COMPACT, 12, 777, compact_hello_body(uid), HELLO_COMPACT_DECODED)],
       "the compact binary HELLO (65-byte body, 79-byte frame)")

    # Version 1 frames: every receiver still decodes them (old firmware, old logs).
    hello1 = json.dumps(HELLO_DOC_V1, separators=(",", ":")).encode()
    ok("v1_hello", [frame_entry(HELLO, 0, 12345, hello1, HELLO_DOC_V1)], "protocol 1 HELLO", version=1)
    v10 = [sample(i, version=1) for i in range(10)]
    ok("v1_samples_10", [frame_entry(SAMPLES, 2, 21000, samples_body(10, v10, version=1),
                                     {"index": 10, "samples": v10})], "protocol 1: 22-byte records", version=1)
    v40 = [sample(i, t0=5, dt=1000, version=1) for i in range(40)]
    ok("v1_samples_40", [frame_entry(SAMPLES, 8, 42000, samples_body(400, v40, version=1),
                                     {"index": 400, "samples": v40})], "protocol 1 longest frame", version=1)
    ok("v1_status", [frame_entry(STATUS, 7, 99000, status_body(st, 1), st)], "protocol 1 STATUS", version=1)

    good_a = frame_entry(SAMPLES, 20, 5000, samples_body(100, s1), {"index": 100, "samples": s1})
    good_b = frame_entry(STATUS, 21, 6000, status_body(st3), st3)
    wa = wire(frame_bytes(SAMPLES, 20, 5000, bytes.fromhex(good_a["body"])))
    wb = wire(frame_bytes(STATUS, 21, 6000, bytes.fromhex(good_b["body"])))

    def broken(name, stream, frames, errors, note):
        cases.append({"name": name, "version": VERSION, "note": note, "wire": stream.hex(), "frames": frames,
                      "errors": errors, "encode": False})

    bad = bytearray(frame_bytes(SAMPLES, 20, 5000, bytes.fromhex(good_a["body"])))
    bad[12] ^= 0x10
    broken("crc_bitflip", wire(bytes(bad)) + wb, [good_b], {"crc": 1},
           "one flipped body bit, re-stuffed so COBS is intact: only the CRC can catch it")
    broken("garbage_then_frame", b"\x13\x37\xff\xfe\x01" + wb + wa, [good_a], {"crc": 1},
           "noise glued to the front of a frame spoils that frame; the one after it is recovered")
    glued = wa[:len(wa) // 2] + wb
    try:  # whether the glued chunk still parses as COBS depends on the bytes: ask the reference
        cobs.decode(glued[:-1])
        kind = "crc"
    except cobs.DecodeError:
        kind = "cobs"
    broken("truncated_frame", glued, [], {kind: 1},
           "the first half of a frame runs into the next frame: one corrupt chunk, both lost")
    broken("truncated_then_delim", wa[:len(wa) // 2] + b"\x00" + wb, [good_b], {"cobs": 1},
           "a frame cut short and followed by a delimiter: the next frame survives")
    broken("version_newer", wire(frame_bytes(STATUS, 21, 6000, status_body(st3), version=4)) + wa, [good_a],
           {"version_newer": 1}, "a valid frame of a newer protocol (4): the log needs a newer stid")
    broken("bad_version_0", wire(frame_bytes(STATUS, 21, 6000, status_body(st3), version=0)) + wa, [good_a],
           {"version": 1}, "unknown protocol version (0)")
    broken("bad_type", wire(frame_bytes(9, 21, 6000, status_body(st3))) + wa, [good_a], {"type": 1},
           "unknown frame type")
    broken("v2_status_length_in_v3", wire(frame_bytes(STATUS, 21, 6000, status_body(st, 2))) + wa, [good_a],
           {"length": 1}, "a 28-byte STATUS under version 3 (34 expected)")
    broken("v2_hello_compact", wire(frame_bytes(HELLO_COMPACT, 21, 6000, compact_hello_body(uid), version=2)) + wa,
           [good_a], {"type": 1}, "the compact HELLO does not exist before version 3")
    short_uid = compact_hello_body(uid)[:-1]
    broken("hello_compact_uid_len", wire(frame_bytes(HELLO_COMPACT, 21, 6000, short_uid)) + wa, [good_a],
           {"hello": 1}, "a compact HELLO one byte shorter than its uid_len says")
    broken("v1_samples4", wire(frame_bytes(SAMPLES4, 21, 6000, samples_body(0, s4, four=True), version=1)) + wa,
           [good_a], {"type": 1}, "SAMPLES4 does not exist in protocol 1")
    broken("bad_length", wire(frame_bytes(SAMPLES, 21, 6000, samples_body(0, s1) + b"\x01")) + wa, [good_a],
           {"length": 1}, "SAMPLES body one byte longer than 5 + 26 n")
    broken("v1_length_in_v2", wire(frame_bytes(SAMPLES, 21, 6000, samples_body(0, v10[:2], version=1))) + wa,
           [good_a], {"length": 1}, "22-byte records under version 2: 5 + 44 is not 5 + 26 n")
    broken("v2_length_in_v1", wire(frame_bytes(SAMPLES, 21, 6000, samples_body(0, s10[:11]), version=1)) + wa,
           [good_a], {"length": 1}, "26-byte records under version 1")
    broken("bad_length4", wire(frame_bytes(SAMPLES4, 21, 6000, samples_body(0, s1))) + wa, [good_a],
           {"length": 1}, "a 26-byte record in a SAMPLES4 frame (5 + 44 n expected)")
    broken("samples_n0", wire(frame_bytes(SAMPLES, 21, 6000, samples_body(0, s10[:0]))) + wa, [good_a],
           {"length": 1}, "a SAMPLES frame of no records: n is 1 to 38")
    broken("short", wire(b"\x01\x02\x03") + wa, [good_a], {"short": 1}, "shorter than header + CRC")
    broken("bad_cobs", bytes([0x09, 0x41, 0x42, 0x00]) + wa, [good_a], {"cobs": 1},
           "a COBS code byte that points past the end of the frame")
    broken("too_long", b"\x55" * 1500 + b"\x00" + wa, [good_a], {"too_long": 1},
           "1500 non-zero bytes: more than any frame, discarded without buffering it all")
    broken("empty_frames", b"\x00\x00" + wa + b"\x00", [good_a], {},
           "delimiters with nothing between them are not errors")
    return cases


def write_txt(cases, path):
    lines = ["# stid golden vectors (generated by make_vectors.py; do not edit)"]
    for c in cases:
        lines.append(f"case {c['name']}")
        lines.append(f"version {c['version']}")
        lines.append(f"wire {c['wire']}")
        for f in c["frames"]:
            lines.append(f"frame {f['type']} {f['seq']} {f['t_us']} {f['body']}")
        errs = " ".join(f"{k}={v}" for k, v in sorted(c["errors"].items()))
        lines.append(f"errors {errs}".rstrip())
        if c["encode"]:
            lines.append("encode")
        lines.append("end")
    path.write_text("\n".join(lines) + "\n")


def main():
    cases = build_cases()
    doc = {"protocol": VERSION, "sample_fields": SAMPLE_FIELDS, "wheels3_fields": WHEELS3_FIELDS,
           "sample_fields_v1": SAMPLE_FIELDS_V1, "status_fields": STATUS_FIELDS,
           "status_fields_v2": STATUS_FIELDS_V2, "cases": cases}
    (HERE / "vectors.json").write_text(json.dumps(doc, indent=1) + "\n")
    write_txt(cases, HERE / "vectors.txt")
    print(f"wrote {len(cases)} cases")


if __name__ == "__main__":
    main()
