# Is this MicroPython's small int 31 bits, as on a board? The sampler's old step
# `(t_next + period) & mask`, run across the tick wrap with the heap locked as in a
# hard interrupt: on a 31-bit port the intermediate t_next + period >= 2^30 is a
# heap object, a MemoryError; on the 64-bit unix port nothing happens. Prints
# "maxsize N memory_errors M" for the pytest wrapper to judge.
import sys

import micropython

MASK30 = 0x3FFFFFFF


def old_step(t_next, period):
    return (t_next + period) & MASK30


def locked_step(t, period):
    # the step with the heap locked: (new t, True) or (t, False) on a MemoryError
    micropython.heap_lock()
    try:
        t = old_step(t, period)
        ok = True
    except MemoryError:
        ok = False
    micropython.heap_unlock()
    return t, ok


def across_the_wrap():
    errors = 0
    t = MASK30 - 20 * 2000
    for _ in range(40):
        t, ok = locked_step(t, 2000)
        if not ok:
            errors += 1
            t = old_step(t, 2000)  # the same step with the heap free: on across the wrap
    return errors


print("maxsize %d memory_errors %d" % (sys.maxsize, across_the_wrap()))
