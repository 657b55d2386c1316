# The MicroPython encoder must reproduce every clean golden vector byte for byte.
# usage: micropython mp_vectors.py VECTORS.json
import json
import struct
import sys
import binascii

import codec
from mptest import check, done

doc = json.load(open(sys.argv[1]))
check(codec.CRC_TABLE[4:8] == struct.pack("<I", 0x77073096), "crc table entry 1")
for case in doc["cases"]:
    if not case["encode"] or case["version"] != codec.VERSION:
        continue  # the firmware only encodes the current version
    enc = codec.FrameEncoder()
    wire = bytearray()
    for fr in case["frames"]:
        enc.seq = fr["seq"]
        body = binascii.unhexlify(fr["body"])
        if fr["type"] in (codec.SAMPLES, codec.SAMPLES4):
            d = fr["decoded"]
            off = enc.samples_begin(fr["t_us"], d["index"], len(d["samples"]), fr["type"])
            for s in d["samples"]:
                struct.pack_into(codec.SAMPLE_FMT, enc.raw, off, *[s[k] for k in doc["sample_fields"]])
                off += codec.SAMPLE_SIZE
                if fr["type"] == codec.SAMPLES4:
                    struct.pack_into(codec.WHEELS3_FMT, enc.raw, off, *[s[k] for k in doc["wheels3_fields"]])
                    off += codec.SAMPLE4_SIZE - codec.SAMPLE_SIZE
            n = enc.finish(off - codec.HEADER_SIZE)
        elif fr["type"] == codec.STATUS:
            d = fr["decoded"]
            n = enc.status(fr["t_us"], *[d[k] for k in doc["status_fields"]])
        else:  # HELLO and HELLO_COMPACT: the body is built once at boot, sent as is
            n = enc.hello(fr["t_us"], body, fr["type"])
        wire += enc.wire[:n]
    check(binascii.hexlify(wire).decode() == case["wire"], "encode " + case["name"])
done()
