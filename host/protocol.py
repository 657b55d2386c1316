"""Constants and record layouts of the stid wire protocol (firmware/PROTOCOL.md).

This module mirrors the spec; it holds no logic. numpy dtypes let the host turn
the sample records of many frames into arrays in one call.
"""

import numpy as np

VERSION = 1
HELLO, SAMPLES, STATUS = 1, 2, 3
TYPE_NAMES = {HELLO: "hello", SAMPLES: "samples", STATUS: "status"}

MOD = 1 << 30  # seq, t_us and sample index all count modulo 2^30
HEADER_SIZE = 10
CRC_SIZE = 4
MAX_FRAME = 1024  # bytes before COBS
MAX_WIRE = MAX_FRAME + MAX_FRAME // 254 + 2  # COBS worst case, delimiter excluded
MISSING = 0xFFFF  # a field the board does not sample

HEADER_FMT = "<BBII"
SAMPLES_HEAD_FMT = "<IB"
SAMPLES_HEAD_SIZE = 5
SAMPLE_SIZE = 22
MAX_BATCH = 40

SAMPLE_DTYPE = np.dtype([
    ("t_us", "<u4"), ("ax", "<u2"), ("ay", "<u2"), ("az", "<u2"), ("yaw", "<u2"),
    ("steer_us", "<u2"), ("wheel_count", "<u2"), ("wheel_t_us", "<u4"), ("vbat", "<u2"),
])
assert SAMPLE_DTYPE.itemsize == SAMPLE_SIZE
SAMPLE_FIELDS = SAMPLE_DTYPE.names

STATUS_FMT = "<IIIIIHHHH"
STATUS_FIELDS = ("uptime_ms", "samples", "overruns", "frames", "tx_short",
                 "isr_max_us", "isr_last_us", "ring_peak", "ring_size")
STATUS_SIZE = 28

ERROR_KINDS = ("cobs", "short", "crc", "version", "type", "length", "hello", "too_long")
