"""Identify while driving: from a run that is still being written, every few seconds,
each parameter's value and 95% precision, what the data still lack in a driver's words,
a "done" line when every target is reached, and the diagnosis's first answer.

The modules, in data-flow order: ``source`` (what the growing file holds so far, and
what is wrong with it), ``estimator`` (the fit ``stid fit`` makes, warm-started),
``lacks`` (what to drive next), ``excitation`` (the speed x frequency map),
``diagnosis`` (``stid diagnose`` in the background), ``targets``; then the views:
``terminal`` and ``web`` (with ``page.html``), and ``follow``, the loop that ties them.
The logger starts it as a process of its own (``stid-log --live``): estimation never
costs the logger a sample.
"""
