"""The search for the effect a model is missing, in the pieces stid.diagnose composes:

- ``candidate``: a candidate effect, its likelihood-ratio statistic and chance in words;
- ``screen``: the linearised step that decides which candidates get a full fit;
- ``pairs``: a candidate whose evidence fails, fitted jointly with each other effect;
- ``explain``: the sentences a vehicle engineer reads for a candidate;
- ``pool``: the worker processes the independent fits share.

Nothing here prints: stid.present lays the results out, and nothing here imports it."""
