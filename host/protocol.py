"""Constants and record layouts of the stid wire protocol (firmware/PROTOCOL.md).

This module mirrors the spec; it holds no logic beyond turning records into
arrays. numpy dtypes let the host turn the sample records of many frames into
arrays in one call.

Versions: the receiver accepts every version in ``VERSIONS``; the header's
version byte and the frame type together name the record layout
(``RECORD_DTYPES``). Version 1 (22-byte records, no steer time) is still decoded:
its samples get ``steer_t_us = STEER_T_UNKNOWN``. Version 3 keeps the version 2
sample records, lengthens STATUS (``missed``, ``late_max_us``) and adds the
compact binary HELLO (type 5, ``HELLO_COMPACT``).
"""

import numpy as np

VERSION = 3  # what the firmware sends
VERSIONS = (1, 2, 3)  # what the host decodes
HELLO, SAMPLES, STATUS, SAMPLES4, HELLO_COMPACT = 1, 2, 3, 4, 5
TYPE_NAMES = {HELLO: "hello", SAMPLES: "samples", STATUS: "status", SAMPLES4: "samples4",
              HELLO_COMPACT: "hello_compact"}
SAMPLE_TYPES = (SAMPLES, SAMPLES4)

MOD = 1 << 30  # seq, t_us and sample index all count modulo 2^30
# The baud the firmware sets on a UART link (ESP32 console; boards.py PROFILES): the
# default a host should open a port at (USB-CDC ignores it)
LINK_BAUD = 921600
HEADER_SIZE = 10
CRC_SIZE = 4
MAX_FRAME = 1024  # bytes before COBS
MAX_WIRE = MAX_FRAME + MAX_FRAME // 254 + 2  # COBS worst case, delimiter excluded
MISSING = 0xFFFF  # a field the board does not sample
STEER_T_UNKNOWN = 0xFFFFFFFF  # steer_t_us of a version 1 sample (the wire did not carry it)
WHEEL_T_MISSING = 0xFFFFFFFF  # wheelK_t_us of a wheel the frame does not carry
WHEEL_COUNT_MISSING = 0xFFFF

HEADER_FMT = "<BBII"
SAMPLES_HEAD_FMT = "<IB"
SAMPLES_HEAD_SIZE = 5

_V1_FIELDS = [
    ("t_us", "<u4"), ("ax", "<u2"), ("ay", "<u2"), ("az", "<u2"), ("yaw", "<u2"),
    ("steer_us", "<u2"), ("wheel_count", "<u2"), ("wheel_t_us", "<u4"), ("vbat", "<u2"),
]
_WHEELS3 = [(f"wheel{k}_{f}", t) for k in (1, 2, 3) for f, t in (("count", "<u2"), ("t_us", "<u4"))]

SAMPLE_DTYPE_V1 = np.dtype(_V1_FIELDS)  # version 1, type 2: 22 bytes
SAMPLE_DTYPE = np.dtype(_V1_FIELDS + [("steer_t_us", "<u4")])  # version 2, type 2: 26 bytes
SAMPLE4_DTYPE = np.dtype(_V1_FIELDS + [("steer_t_us", "<u4")] + _WHEELS3)  # version 2, type 4: 44 bytes
assert (SAMPLE_DTYPE_V1.itemsize, SAMPLE_DTYPE.itemsize, SAMPLE4_DTYPE.itemsize) == (22, 26, 44)
SAMPLE_SIZE = SAMPLE_DTYPE.itemsize
SAMPLE4_SIZE = SAMPLE4_DTYPE.itemsize

RECORD_DTYPES = {(1, SAMPLES): SAMPLE_DTYPE_V1, (2, SAMPLES): SAMPLE_DTYPE, (2, SAMPLES4): SAMPLE4_DTYPE,
                 (3, SAMPLES): SAMPLE_DTYPE, (3, SAMPLES4): SAMPLE4_DTYPE}

# Every field a decoded sample has, whatever its frame carried (the union, in record order).
SAMPLE_FIELDS = SAMPLE4_DTYPE.names
DECODED_DTYPE = np.dtype([(n, SAMPLE4_DTYPE[n]) for n in SAMPLE_FIELDS])
FILL = {"steer_t_us": STEER_T_UNKNOWN, **{n: (WHEEL_T_MISSING if n.endswith("_t_us") else WHEEL_COUNT_MISSING)
                                         for n, _ in _WHEELS3}}
WHEEL_FIELDS = [("wheel_count", "wheel_t_us")] + [(f"wheel{k}_count", f"wheel{k}_t_us") for k in (1, 2, 3)]


def max_batch(version: int, ftype: int) -> int:
    """Most records of this layout that fit one frame (40, 38, 22)."""
    if version == 1:
        return 40
    return (MAX_FRAME - HEADER_SIZE - CRC_SIZE - SAMPLES_HEAD_SIZE) // RECORD_DTYPES[(version, ftype)].itemsize


def records_to_samples(version: int, ftype: int, data: bytes) -> np.ndarray:
    """Sample records of one layout (concatenated) -> DECODED_DTYPE array, absent fields filled."""
    raw = np.frombuffer(data, dtype=RECORD_DTYPES[(version, ftype)])
    out = np.empty(len(raw), DECODED_DTYPE)
    for name in SAMPLE_FIELDS:
        if name in raw.dtype.names:
            out[name] = raw[name]
        else:
            out[name] = FILL[name]
    return out


def samples_from_records(parts) -> np.ndarray:
    """(version, type, records) of consecutive frames -> one DECODED_DTYPE array.
    Runs of one layout are decoded together (one numpy call per run, not per frame)."""
    out, run, key = [], [], None
    for version, ftype, data in parts:
        if (version, ftype) != key and run:
            out.append(records_to_samples(*key, b"".join(run)))
            run = []
        key = (version, ftype)
        run.append(data)
    if run:
        out.append(records_to_samples(*key, b"".join(run)))
    if not out:
        return np.zeros(0, DECODED_DTYPE)
    return out[0] if len(out) == 1 else np.concatenate(out)


STATUS_FIELDS_V2 = ("uptime_ms", "samples", "overruns", "frames", "tx_short",
                    "isr_max_us", "isr_last_us", "ring_peak", "ring_size")
# version 3 appends the timer periods in which no sample was taken (their indices are
# skipped, so the host sees the gap) and the largest lateness of a sample instant
STATUS_FIELDS = STATUS_FIELDS_V2 + ("missed", "late_max_us")
STATUS_LAYOUTS = {1: ("<IIIIIHHHH", STATUS_FIELDS_V2), 2: ("<IIIIIHHHH", STATUS_FIELDS_V2),
                  3: ("<IIIIIHHHHIH", STATUS_FIELDS)}
STATUS_FMT = STATUS_LAYOUTS[VERSION][0]
STATUS_SIZE = 34  # version 3; versions 1 and 2: 28
STATUS_SIZES = {1: 28, 2: 28, 3: 34}

# version byte 0 or unknown -> "version"; a CRC-valid frame of a version above
# max(VERSIONS) -> "version_newer" (the log needs a newer stid)
ERROR_KINDS = ("cobs", "short", "crc", "version", "version_newer", "type", "length", "hello", "too_long")


# Compact HELLO (type 5, version 3): the configuration in ~80 bytes so that it gets
# through a lossy link (PROTOCOL.md, "HELLO_COMPACT"). Fixed part, then `uid_len`
# bytes of machine.unique_id(). Codes index the tuples below.
HELLO_C_FMT = "<IBBHB3B3BBBBHH" + "BH" * 5 + "HIBB4sBIHB"
HELLO_C_FIELDS = ("boot_id", "board", "flags", "rate_hz", "batch", "fw0", "fw1", "fw2", "mp0", "mp1", "mp2",
                  "reset_cause", "adc_bits", "adc_unit", "adc_vref_mv", "adc_clip_mv",
                  *(f"{c}_{k}" for c in ("ax", "ay", "az", "yaw", "vbat") for k in ("part", "bw")),
                  "steer_period_us", "steer_timeout_us", "wheel_ppr", "n_wheels", "wheel_pos",
                  "link_kind", "link_baud", "link_bps_x100", "uid_len")
HELLO_C_FIXED = 57
HELLO_C_BOARDS = ("unknown", "pico", "esp32")
HELLO_C_FLAG_HARD_TIMER = 1
HELLO_C_FLAG_SIM = 2
HELLO_C_FLAG_ADC_DMA = 4  # analog channels scanned by the ADC into a DMA ring (else read by the CPU)
HELLO_C_FLAG_SERVO_PIO = 8  # servo pulses timed by a PIO state machine (else pin interrupts)
HELLO_C_FLAG_SERVO_PCNT = 16  # servo pulses timed by the ESP32's pulse counter (firmware 0.3.2)
HELLO_C_FLAG_HALL_PCNT = 32  # hall edges counted and timed by the ESP32's pulse counter (firmware 0.3.3)
HELLO_C_RESET_CAUSES = ("unknown", "power_on", "hard", "watchdog", "deepsleep", "soft")
HELLO_C_PARTS = (None, ("ADXL335", "ratiometric"), ("LISY300AL", "absolute"), ("divider", "absolute"))
HELLO_C_ADC_UNITS = ("count", "mV")
HELLO_C_WHEELS = ("fl", "fr", "rl", "rr")
HELLO_C_LINKS = (None, "usb", "uart", "pipe")
CHANNEL_NAMES = ("ax", "ay", "az", "yaw", "vbat")
# keys version 3 added to HELLO; a version 1/2 HELLO reads them as None
HELLO_V3_KEYS = ("uid", "micropython", "timer", "reset_cause", "link")
