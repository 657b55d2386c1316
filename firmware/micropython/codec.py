# stid wire codec for MicroPython (firmware/PROTOCOL.md).
# Everything here works in preallocated buffers: building a frame allocates
# nothing, so the main loop never triggers a garbage collection that would delay
# the sampler. The CRC and COBS loops are viper (native machine words): the CRC
# result never becomes a Python int, which on 32-bit ports would be a heap-
# allocated big int whenever it is >= 2^30.
import micropython
import struct
from micropython import const

VERSION = const(3)
HELLO = const(1)
SAMPLES = const(2)  # records of SAMPLE_SIZE: one hall sensor
STATUS = const(3)
SAMPLES4 = const(4)  # records of SAMPLE4_SIZE: four hall sensors
HELLO_COMPACT = const(5)  # the configuration in ~65 bytes, for lossy links
MASK30 = const(0x3FFFFFFF)
HEADER_SIZE = const(10)
SAMPLES_HEAD = const(5)
SAMPLE_SIZE = const(26)
SAMPLE4_SIZE = const(44)
STATUS_SIZE = const(34)
MAX_FRAME = const(1024)
MAX_WIRE = const(1030)  # COBS worst case for 1024 bytes + delimiter
# t_us ax ay az yaw steer_us wheel_count wheel_t_us vbat steer_t_us
SAMPLE_FMT = "<IHHHHHHIHI"
# appended in SAMPLES4 records: (count, t_us) of wheels 1, 2, 3
WHEELS3_FMT = "<HIHIHI"
STATUS_FMT = "<IIIIIHHHHIH"
# compact HELLO (PROTOCOL.md): fixed part, then uid_len bytes of machine.unique_id()
HELLO_C_FMT = "<IBBHB3B3BBBBHH" + "BH" * 5 + "HIBB4sBIHB"


def add30(a, k):
    # (a + k) mod 2^30 for a counter a in [0, 2^30) and 0 <= k < 2^30, without forming
    # a + k: on a board (31-bit small ints) a value >= 2^30 is a heap-allocated big int,
    # and in a hard interrupt that is a MemoryError
    room = MASK30 - a
    return a + k if k <= room else k - room - 1


def _make_crc_table():
    table = bytearray(1024)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        struct.pack_into("<I", table, 4 * i, c)
    return table


CRC_TABLE = _make_crc_table()


@micropython.viper
def crc32_store(buf: ptr8, n: int, table: ptr32):
    # CRC-32 (IEEE, as zlib.crc32) of buf[0:n], stored little-endian at buf[n:n+4].
    ones = uint(0xFFFF) | (uint(0xFFFF) << 16)
    crc = ones
    i = 0
    while i < n:
        crc = uint(table[(crc ^ uint(buf[i])) & 0xFF]) ^ (crc >> 8)
        i += 1
    crc = crc ^ ones
    buf[n] = crc & 0xFF
    buf[n + 1] = (crc >> 8) & 0xFF
    buf[n + 2] = (crc >> 16) & 0xFF
    buf[n + 3] = (crc >> 24) & 0xFF


@micropython.viper
def cobs_encode(src: ptr8, n: int, dst: ptr8) -> int:
    # COBS-encode src[0:n] into dst and append the 0x00 delimiter; return length.
    # Like the reference (PyPI cobs), a final full 254-byte block gets no extra code.
    code_i = 0
    o = 1
    code = 1
    i = 0
    open_block = 1
    while i < n:
        b = src[i]
        i += 1
        if b == 0:
            dst[code_i] = code
            code_i = o
            o += 1
            code = 1
        else:
            dst[o] = b
            o += 1
            code += 1
            if code == 0xFF:
                dst[code_i] = code
                if i < n:
                    code_i = o
                    o += 1
                    code = 1
                else:
                    open_block = 0
    if open_block:
        dst[code_i] = code
    dst[o] = 0
    return o + 1


@micropython.viper
def copy_bytes(dst: ptr8, doff: int, src: ptr8, soff: int, n: int):
    i = 0
    while i < n:
        dst[doff + i] = src[soff + i]
        i += 1


class FrameEncoder:
    """Builds frames in one reusable buffer: header, body, CRC, COBS."""

    def __init__(self):
        self.raw = bytearray(MAX_FRAME + 4)
        self.wire = bytearray(MAX_WIRE)
        self.seq = 0

    def header(self, ftype, t_us):
        struct.pack_into("<BBII", self.raw, 0, VERSION, ftype, self.seq, t_us & MASK30)

    def finish(self, body_len):
        # Seal the frame whose body is raw[10:10+body_len]; return its wire length.
        n = HEADER_SIZE + body_len
        crc32_store(self.raw, n, CRC_TABLE)
        self.seq = add30(self.seq, 1)
        return cobs_encode(self.raw, n + 4, self.wire)

    def hello(self, t_us, doc_bytes, ftype=HELLO):
        # doc_bytes: the JSON document (HELLO) or the packed compact body (HELLO_COMPACT)
        self.header(ftype, t_us)
        copy_bytes(self.raw, HEADER_SIZE, doc_bytes, 0, len(doc_bytes))
        return self.finish(len(doc_bytes))

    def status(self, t_us, uptime_ms, samples, overruns, frames, tx_short,
               isr_max_us, isr_last_us, ring_peak, ring_size, missed, late_max_us):
        self.header(STATUS, t_us)
        struct.pack_into(STATUS_FMT, self.raw, HEADER_SIZE, uptime_ms & MASK30, samples & MASK30,
                         overruns & MASK30, frames & MASK30, tx_short & MASK30,
                         min(isr_max_us, 0xFFFF), min(isr_last_us, 0xFFFF), ring_peak, ring_size,
                         missed & MASK30, min(late_max_us, 0xFFFF))
        return self.finish(STATUS_SIZE)

    def samples_begin(self, t_us, index, n, ftype=SAMPLES):
        # The caller then copies n records (SAMPLE_SIZE, or SAMPLE4_SIZE for SAMPLES4)
        # to raw[15:].
        self.header(ftype, t_us)
        struct.pack_into("<IB", self.raw, HEADER_SIZE, index & MASK30, n)
        return HEADER_SIZE + SAMPLES_HEAD


def max_batch(record_size):
    # Most records that fit one frame: 38 of SAMPLE_SIZE, 22 of SAMPLE4_SIZE.
    return (MAX_FRAME - HEADER_SIZE - 4 - SAMPLES_HEAD) // record_size
