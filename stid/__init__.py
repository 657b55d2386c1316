"""stid: single-track identification for scale cars.

Loads runs logged by ``stid-log`` (MCAP) or CSV, calibrates them, fits the
single-track ("bicycle") vehicle model and its effects, and diagnoses where the
model fails. Units are SI inside, axes ISO 8855, cornering stiffness per axle in
N/rad.
"""

__version__ = "0.1.0"
