"""numpy, imported when first used (the standard library's importlib.util.LazyLoader).

The effect catalogue is imported by `stid --help` (it lists the effects and their
parameters) and by every command; numpy is ~60 ms of a 0.15 s budget for help, and the
catalogue's modules use it only inside their functions. Modules on that path write
``from stid.lazy_numpy import np``; everywhere else ``import numpy as np`` is as good.
"""

import importlib.util
import sys


def _lazy(name: str):
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module


np = _lazy("numpy")
