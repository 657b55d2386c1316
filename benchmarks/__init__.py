"""Benchmarks: `make bench` (full) or `python -m benchmarks.run --quick` (CI smoke)."""
