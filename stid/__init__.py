"""stid: single-track identification for scale cars.

Loads runs logged by ``stid-log`` (MCAP) or CSV, calibrates them, fits the
single-track ("bicycle") vehicle model and its effects, and diagnoses where the
model fails. Units are SI inside, axes ISO 8855, cornering stiffness per axle in
N/rad.
"""

__version__ = "0.1.0"

import os as _os

# One BLAS thread. Our matrices are small (at most ~500 square) and the work is many of
# them; OpenBLAS's extra threads busy-wait for each other, and when other processes share
# the cores (diagnose's candidate workers, a test run, a simulator) that made the noise
# floor 35x slower on 2 cores (36 s vs 1.0 s, measured). Set before numpy loads; a user's
# own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
