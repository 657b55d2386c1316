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
