# Encode pseudo-random frames (many zeros, lengths across COBS block boundaries)
# and print them as hex; the pytest side checks them with the reference `cobs`
# package and zlib.
# usage: micropython mp_cobs_random.py N SEED
import sys
import binascii

import codec

n, seed = int(sys.argv[1]), int(sys.argv[2])
state = seed


def rnd(k):
    global state
    state = (state * 1103515245 + 12345) & 0x7FFFFFFF
    return state % k


enc = codec.FrameEncoder()
for i in range(n):
    length = [0, 1, 239, 240, 241, 244, 493, 494, 1010][i % 9] if i < 9 else rnd(1011)
    enc.header(rnd(4), rnd(1 << 30))
    zero_rate = rnd(4)
    for j in range(length):
        enc.raw[10 + j] = 0 if rnd(4) < zero_rate else 1 + rnd(255)
    w = enc.finish(length)
    print(binascii.hexlify(enc.raw[:10 + length + 4]).decode(), binascii.hexlify(enc.wire[:w]).decode())
