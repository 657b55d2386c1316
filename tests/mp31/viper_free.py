# Python renderings of codec.py's three viper functions, for the webassembly port
# (no native emitter: run.mjs puts these in their place). Same results, byte for
# byte (tests/mp31/mp31_codec.py checks them against the golden vectors), and no
# value ever reaches 2^30, so they too run under micropython.heap_lock() on 31-bit
# small ints: the CRC is kept in two 16-bit halves.


def crc32_store(buf, n, table):
    # CRC-32 (IEEE, as zlib.crc32) of buf[0:n], stored little-endian at buf[n:n+4];
    # table: codec.CRC_TABLE (256 little-endian u32)
    lo = 0xFFFF
    hi = 0xFFFF
    i = 0
    while i < n:
        k = ((lo ^ buf[i]) & 0xFF) << 2
        lo = ((lo >> 8) | ((hi & 0xFF) << 8)) ^ (table[k] | (table[k + 1] << 8))
        hi = (hi >> 8) ^ (table[k + 2] | (table[k + 3] << 8))
        i += 1
    lo ^= 0xFFFF
    hi ^= 0xFFFF
    buf[n] = lo & 0xFF
    buf[n + 1] = lo >> 8
    buf[n + 2] = hi & 0xFF
    buf[n + 3] = hi >> 8


def cobs_encode(src, n, dst):
    # COBS-encode src[0:n] into dst and append the 0x00 delimiter; return length
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


def copy_bytes(dst, doff, src, soff, n):
    i = 0
    while i < n:
        dst[doff + i] = src[soff + i]
        i += 1
