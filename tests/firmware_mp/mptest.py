# A minimal test harness for MicroPython (the unix port has no unittest):
# each check prints one line; the pytest wrapper fails on any FAIL line.
import sys

_failed = 0
_passed = 0


def check(cond, name):
    global _failed, _passed
    if cond:
        _passed += 1
        print("PASS", name)
    else:
        _failed += 1
        print("FAIL", name)


def done():
    print("%d passed, %d failed" % (_passed, _failed))
    sys.exit(1 if _failed else 0)


def run_heap_locked(board, fw, steps):
    """Drive the board and the app's main loop ``steps`` times with the heap locked (stopping
    early if the app escaped): False if anything allocated. A function, because a new
    module-level name would itself allocate (the globals dict)."""
    import micropython

    micropython.heap_lock()
    try:
        n = 0
        while n < steps and not getattr(fw, "escaped", False):
            board.idle()
            fw.pump()
            fw.service()
            n += 1
        ok = True
    except MemoryError:
        ok = False
    micropython.heap_unlock()
    return ok
