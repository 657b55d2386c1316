"""Fitting: steady state, frequency domain, time domain, two-step."""
