# Ring buffer semantics: order, wrap-around, overrun counting, gap handling.
import struct

import codec
from mptest import check, done
from ring import SampleRing

r = SampleRing(8)


def push(i):
    r.push(i, 1000 * i, i, i + 1, i + 2, i + 3, 1500, i & 0xFFFF, 7 * i, 0xFFFF, 999 * i)


for i in range(6):
    push(i)
check(r.fill() == 6 and r.run_length(10) == 6, "fill and run length")
dst = bytearray(300)
r.copy_into(dst, 0, 4)
check(r.fill() == 6 and r.first_index() == 0, "a copy releases nothing (the write may not complete)")
r.release(4)
check(r.fill() == 2 and r.first_index() == 4, "released once sent")
check(struct.unpack_from(codec.SAMPLE_FMT, dst, 3 * 26)[0] == 3000, "copy keeps order")
check(struct.unpack_from(codec.SAMPLE_FMT, dst, 3 * 26)[9] == 2997, "steer_t_us kept")
for i in range(6, 12):  # wraps around the end of the buffer
    push(i)
check(r.fill() == 8 and r.overruns == 0, "full without overrun")
push(12)
push(13)
check(r.overruns == 2 and r.fill() == 8, "overrun counted, sample dropped")
check(r.first_index() == 4 and r.run_length(40) == 8, "run length over wrap")
r.copy_into(dst, 5, 8)
r.release(8)
ts = [struct.unpack_from(codec.SAMPLE_FMT, dst, 5 + 26 * k)[0] for k in range(8)]
check(ts == [1000 * i for i in range(4, 12)], "wrap-around copy in order")
push(14)  # 12 and 13 were dropped: 14 follows a gap
push(15)
check(r.first_index() == 14 and r.run_length(40) == 2, "after gap")
r2 = SampleRing(8)
r2.push(1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
r2.push(3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
check(r2.run_length(40) == 1, "a frame never spans an index gap")
check(r.peak == 8, "peak fill")
# counters near 2^30 wrap without ever forming 2^30 (a big int on a board)
r3 = SampleRing(4)
r3.head = r3.tail = codec.MASK30 - 1
for i in range(3):
    r3.push(i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
check(r3.head == 1 and r3.fill() == 3, "head wraps at 2^30 (%d)" % r3.head)
r3.release(3)
check(r3.tail == 1 and r3.fill() == 0, "tail wraps at 2^30")
check(codec.add30(codec.MASK30, 1) == 0 and codec.add30(5, 3) == 8 and codec.add30(codec.MASK30 - 2, 10) == 7,
      "add30 is (a + k) mod 2^30")
# four-wheel records: the producer packs into the claimed slot, the consumer copies 44 bytes
r4 = SampleRing(4, codec.SAMPLE4_SIZE)
for i in range(5):
    off = r4.claim(i)
    if off >= 0:
        struct.pack_into(codec.SAMPLE_FMT, r4.buf, off, i, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        struct.pack_into(codec.WHEELS3_FMT, r4.buf, off + codec.SAMPLE_SIZE, i, 10 * i, 0, 0, 0, 7 * i)
        r4.commit()
check(r4.overruns == 1 and r4.fill() == 4, "four-wheel ring full, one dropped")
dst4 = bytearray(4 * codec.SAMPLE4_SIZE)
r4.copy_into(dst4, 0, 4)
r4.release(4)
check(struct.unpack_from(codec.WHEELS3_FMT, dst4, 3 * 44 + 26) == (3, 30, 0, 0, 0, 21), "four-wheel record kept")
done()
