"""Regenerate the golden vectors of the stid wire protocol (PROTOCOL.md).

The vectors are built with the third-party ``cobs`` package and ``zlib`` only —
deliberately not with any stid code — so that an error in our encoders or
decoders cannot leak into the reference they are tested against.

    python firmware/vectors/make_vectors.py      # rewrites vectors.json and vectors.txt

``vectors.json`` is read by the Python and MicroPython tests; ``vectors.txt`` is
the same content in a line format the C test reads without a JSON parser.
"""

import json
import struct
import zlib
from pathlib import Path

from cobs import cobs

HERE = Path(__file__).resolve().parent
MOD = 1 << 30
VERSION = 1
HELLO, SAMPLES, STATUS = 1, 2, 3
SAMPLE_FIELDS = ("t_us", "ax", "ay", "az", "yaw", "steer_us", "wheel_count", "wheel_t_us", "vbat")
SAMPLE_FMT = "<IHHHHHHIH"
STATUS_FIELDS = ("uptime_ms", "samples", "overruns", "frames", "tx_short",
                 "isr_max_us", "isr_last_us", "ring_peak", "ring_size")
STATUS_FMT = "<IIIIIHHHH"


def frame_bytes(ftype, seq, t_us, body, version=VERSION):
    raw = struct.pack("<BBII", version, ftype, seq, t_us) + body
    return raw + struct.pack("<I", zlib.crc32(raw))


def wire(frame):
    return cobs.encode(frame) + b"\x00"


def samples_body(index, samples):
    body = struct.pack("<IB", index, len(samples))
    for s in samples:
        body += struct.pack(SAMPLE_FMT, *(s[k] for k in SAMPLE_FIELDS))
    return body


def status_body(st):
    return struct.pack(STATUS_FMT, *(st[k] for k in STATUS_FIELDS))


def sample(i, t0=1000, dt=2000):
    return {"t_us": (t0 + i * dt) % MOD, "ax": 2048 + i, "ay": 1900 - 7 * i, "az": 0xFFFF,
            "yaw": 2047 + 3 * i, "steer_us": 1500 + i, "wheel_count": (65530 + i) % 65536,
            "wheel_t_us": (t0 + i * dt - 300) % MOD, "vbat": 0xFFFF}


HELLO_DOC = {
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


def frame_entry(ftype, seq, t_us, body, decoded):
    return {"type": ftype, "seq": seq, "t_us": t_us, "body": body.hex(), "decoded": decoded}


def build_cases():
    cases = []

    def ok(name, entries, note=""):
        stream = b"".join(wire(frame_bytes(e["type"], e["seq"], e["t_us"], bytes.fromhex(e["body"]))) for e in entries)
        cases.append({"name": name, "note": note, "wire": stream.hex(), "frames": entries,
                      "errors": {}, "encode": True})

    hello_body = json.dumps(HELLO_DOC, separators=(",", ":")).encode()
    ok("hello", [frame_entry(HELLO, 0, 12345, hello_body, HELLO_DOC)])

    s1 = [sample(0)]
    ok("samples_1", [frame_entry(SAMPLES, 1, 2100, samples_body(0, s1), {"index": 0, "samples": s1})])

    s10 = [sample(i) for i in range(10)]
    ok("samples_10", [frame_entry(SAMPLES, 2, 21000, samples_body(10, s10), {"index": 10, "samples": s10})])

    # Values just below the 2^30 wrap, and zero bytes everywhere COBS must stuff them.
    sw = [{"t_us": MOD - 1, "ax": 0, "ay": 0xFFFF, "az": 0x0100, "yaw": 0x00FF, "steer_us": 0,
           "wheel_count": 0, "wheel_t_us": MOD - 2, "vbat": 0}]
    ok("samples_wrap_zeros", [frame_entry(SAMPLES, MOD - 1, MOD - 1, samples_body(MOD - 1, sw),
                                          {"index": MOD - 1, "samples": sw})],
       "counters at 2^30 - 1 and many zero bytes")

    st = {"uptime_ms": 61000, "samples": 30500, "overruns": 3, "frames": 3111, "tx_short": 1,
          "isr_max_us": 95, "isr_last_us": 41, "ring_peak": 37, "ring_size": 256}
    ok("status", [frame_entry(STATUS, 7, 99000, status_body(st), st)])

    # Longest legal SAMPLES frame (40 samples, 895 bytes): COBS needs a second code block.
    s40 = [sample(i, t0=5, dt=1000) for i in range(40)]
    ok("samples_40", [frame_entry(SAMPLES, 8, 42000, samples_body(400, s40), {"index": 400, "samples": s40})],
       "longest legal frame, COBS code block boundary")

    good_a = frame_entry(SAMPLES, 20, 5000, samples_body(100, s1), {"index": 100, "samples": s1})
    good_b = frame_entry(STATUS, 21, 6000, status_body(st), st)
    wa = wire(frame_bytes(SAMPLES, 20, 5000, bytes.fromhex(good_a["body"])))
    wb = wire(frame_bytes(STATUS, 21, 6000, bytes.fromhex(good_b["body"])))

    def broken(name, stream, frames, errors, note):
        cases.append({"name": name, "note": note, "wire": stream.hex(), "frames": frames,
                      "errors": errors, "encode": False})

    bad = bytearray(frame_bytes(SAMPLES, 20, 5000, bytes.fromhex(good_a["body"])))
    bad[12] ^= 0x10
    broken("crc_bitflip", wire(bytes(bad)) + wb, [good_b], {"crc": 1},
           "one flipped body bit, re-stuffed so COBS is intact: only the CRC can catch it")
    broken("garbage_then_frame", b"\x13\x37\xff\xfe\x01" + wb + wa, [good_a], {"crc": 1},
           "noise glued to the front of a frame spoils that frame; the one after it is recovered")
    broken("truncated_frame", wa[:len(wa) // 2] + wb, [], {"crc": 1},
           "the first half of a frame runs into the next frame: one corrupt chunk, both lost")
    broken("truncated_then_delim", wa[:len(wa) // 2] + b"\x00" + wb, [good_b], {"cobs": 1},
           "a frame cut short and followed by a delimiter: the next frame survives")
    broken("bad_version", wire(frame_bytes(STATUS, 21, 6000, status_body(st), version=2)) + wa, [good_a],
           {"version": 1}, "unknown protocol version")
    broken("bad_type", wire(frame_bytes(9, 21, 6000, status_body(st))) + wa, [good_a], {"type": 1},
           "unknown frame type")
    broken("bad_length", wire(frame_bytes(SAMPLES, 21, 6000, samples_body(0, s1) + b"\x01")) + wa, [good_a],
           {"length": 1}, "SAMPLES body one byte longer than 5 + 22 n")
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
    doc = {"protocol": 1, "sample_fields": SAMPLE_FIELDS, "status_fields": STATUS_FIELDS, "cases": cases}
    (HERE / "vectors.json").write_text(json.dumps(doc, indent=1) + "\n")
    write_txt(cases, HERE / "vectors.txt")
    print(f"wrote {len(cases)} cases")


if __name__ == "__main__":
    main()
