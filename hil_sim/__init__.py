"""hil_sim: the car that is not there.

Truth vehicle dynamics, sensor models and manoeuvres, written apart from the
identifier (this package never imports ``stid``), and a simulated board on which
the real MicroPython firmware runs (firmware in the loop).
"""

import os as _os

# One BLAS thread. Our matrices are small (at most ~500 square) and the work is many of
# them; OpenBLAS's extra threads busy-wait for each other, and when other processes share
# the cores (a test run, the identifier) that made the noise
# floor 35x slower on 2 cores (36 s vs 1.0 s, measured). Set before numpy loads; a user's
# own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
