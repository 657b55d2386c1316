# The stimulus file (hil_sim/stimulus.py writes it), read by the simulated board a
# window at a time as its virtual clock advances: the board's memory is a few
# kilobytes whatever the run's length. Holding the whole file grew the MicroPython
# process with the run: 10 minutes are 18 MB of voltages, read into a bytearray and
# copied into an array, 50 MB resident against 13 MB now (the same bytes out).
#
# Each array of the file (voltage rows, servo widths and rising edges, hall edges and
# their pins) is a _Rows: `buf` holds rows [base, base + cap) and `cover` reloads it
# from the file when a row outside is asked for. The clock only moves forward, so a
# reload starts a little before the row asked for (an ADC conversion can be taken a
# few ms after its instant) and is rare; any row, earlier ones too, can still be read.
#
# Nothing here allocates after __init__: the board reads rows while firing interrupts,
# which the firmware's allocation test runs under micropython.heap_lock(). A reload is
# a seek and a readinto of the whole buffer (a slice would allocate a memoryview); at
# the end of the file it reads less, and bytes past the array are never indexed.
import json
import struct
from array import array

MAGIC = b"STIDSIM2"
# rows held per array by default; STID_SIM_BOARD {"stim_rows": N} sets another (tests
# use a few rows, to reload often, or more rows than the file has, to load it whole)
ROWS = {"volts": 4096, "steer": 1024, "hall": 4096}
_BACK = 32  # rows kept before the row that caused a reload


class _Rows:
    def __init__(self, f, offset, n, width, typecode, itemsize, cap):
        self.f = f
        self.offset = offset
        self.n = n  # rows in the file
        self.width = width  # items per row
        self.row_bytes = width * itemsize
        self.cap = cap if cap < n else (n if n > 0 else 1)
        self.back = _BACK if _BACK < self.cap // 2 else self.cap // 2
        self.buf = array(typecode, bytes(self.cap * self.row_bytes))
        self.base = 0
        self.end = 0  # base + cap once loaded; 0: nothing held yet
        if n > 0:
            self.load(0)

    def load(self, row):
        self.base = row
        self.end = row + self.cap
        self.f.seek(self.offset + row * self.row_bytes)
        self.f.readinto(self.buf)

    def cover(self, lo, hi):
        # hold rows lo..hi (hi - lo < cap); return lo's index into buf in rows
        if lo < self.base or hi >= self.end:
            start = lo - self.back
            room = self.cap - 1 - (hi - lo)
            if lo - start > room:
                start = lo - room
            if start < 0:
                start = 0
            self.load(start)
        return lo - self.base

    def at(self, k):
        # item k of a one-item-per-row array
        if k < self.base or k >= self.end:
            self.cover(k, k)
        return self.buf[k - self.base]


class Stim:
    def __init__(self, path, rows=None):
        f = open(path, "rb")
        if f.read(8) != MAGIC:
            f.close()
            raise OSError("not a stid stimulus file: " + path)
        (hlen,) = struct.unpack("<I", f.read(4))
        h = json.loads(f.read(hlen))
        self.f = f
        self.h = h
        self.board = h["board"]
        self.fs = h["fs_sig"]
        self.n_rows = h["n_rows"]
        self.n_cols = len(h["cols"])
        self.cols = {int(k): v for k, v in h["cols"].items()}
        self.n_steer = h["n_steer"]
        self.n_hall = h["n_hall"]
        self.duration_us = h["duration_us"]
        cap = dict(ROWS)
        if rows:
            for k in cap:
                cap[k] = rows
        off = 12 + hlen
        self.volts = _Rows(f, off, self.n_rows, self.n_cols, "H", 2, cap["volts"])
        off += 2 * self.n_rows * self.n_cols
        self.steer = _Rows(f, off, self.n_steer, 1, "H", 2, cap["steer"])  # pulse widths [us]
        off += 2 * self.n_steer
        self.steer_rise = _Rows(f, off, self.n_steer, 1, "I", 4, cap["steer"])  # their rising edges [us]
        off += 4 * self.n_steer
        self.hall = _Rows(f, off, self.n_hall, 1, "I", 4, cap["hall"])  # hall edge times [us]
        off += 4 * self.n_hall
        self.hall_pin = _Rows(f, off, self.n_hall, 1, "B", 1, cap["hall"])  # the pin of each

    def volt(self, row, col):
        """The stored 0.1 mV value of row ``row``, column ``col`` (any row of the file)."""
        w = self.volts
        return w.buf[w.cover(row, row) * self.n_cols + col]

    def close(self):
        self.f.close()
