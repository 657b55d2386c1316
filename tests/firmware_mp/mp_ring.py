# Ring buffer semantics: order, wrap-around, overrun counting, gap handling.
import struct

import codec
from mptest import check, done
from ring import SampleRing

r = SampleRing(8)


def push(i):
    r.push(i, 1000 * i, i, i + 1, i + 2, i + 3, 1500, i & 0xFFFF, 7 * i, 0xFFFF)


for i in range(6):
    push(i)
check(r.fill() == 6 and r.run_length(10) == 6, "fill and run length")
dst = bytearray(200)
r.pop_into(dst, 0, 4)
check(struct.unpack_from(codec.SAMPLE_FMT, dst, 3 * 22)[0] == 3000, "pop keeps order")
for i in range(6, 12):  # wraps around the end of the buffer
    push(i)
check(r.fill() == 8 and r.overruns == 0, "full without overrun")
push(12)
push(13)
check(r.overruns == 2 and r.fill() == 8, "overrun counted, sample dropped")
check(r.first_index() == 4 and r.run_length(40) == 8, "run length over wrap")
r.pop_into(dst, 5, 8)
ts = [struct.unpack_from(codec.SAMPLE_FMT, dst, 5 + 22 * k)[0] for k in range(8)]
check(ts == [1000 * i for i in range(4, 12)], "wrap-around copy in order")
push(14)  # 12 and 13 were dropped: 14 follows a gap
push(15)
check(r.first_index() == 14 and r.run_length(40) == 2, "after gap")
r2 = SampleRing(8)
r2.push(1, 0, 0, 0, 0, 0, 0, 0, 0, 0)
r2.push(3, 0, 0, 0, 0, 0, 0, 0, 0, 0)
check(r2.run_length(40) == 1, "a frame never spans an index gap")
check(r.peak == 8, "peak fill")
done()
