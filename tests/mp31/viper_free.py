# A Python rendering of codec.py's viper crc32_store, for the webassembly port (no
# native emitter: run.mjs puts it in its place; codec's other viper functions run as
# bytecode unchanged). The same bytes (tests/test_firmware_mp31.py checks the golden
# vectors), and no value ever reaches 2^30, so it too runs under
# micropython.heap_lock() on 31-bit small ints: the CRC is kept in two 16-bit halves.


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
