"""hil_sim: the car that is not there.

Truth vehicle dynamics, sensor models and manoeuvres, written apart from the
identifier (this package never imports ``stid``), and a simulated board on which
the real MicroPython firmware runs (firmware in the loop).
"""
