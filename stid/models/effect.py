"""The seam for physical effects: a small base class, a registry, and entry points.

An effect changes the single-track model at one of three places:

- ``"input"``: the steering path before the tyres (e.g. servo lag). ``apply``
  returns the system with a block in front of the ``delta`` input.
- ``"tyre"``: how side forces build up. ``tyre_options`` returns options for the
  base model (relaxation lengths); a nonlinear tyre effect implements
  ``force_correction`` (force minus its linear part, from the slip angles).
- ``"output"``: what the sensors see (offsets, tilt, mounting position).
  ``apply`` adds states or changes the ``ay`` / ``r`` output rows.

A new effect is one class with ``name``, ``params``, ``stage``, ``physics`` (one
paragraph), ``signature`` (how it shows in the residuals) and the method for its
stage, registered with ``@register_effect`` or through the ``stid.effects`` entry
point group. The contract tests and ``stid diagnose`` pick it up with no other
change. See docs/writing_an_effect.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import ClassVar

import numpy as np

from stid.errors import InputError
from stid.models.linsys import LinSys
from stid.models.params import Param

G = 9.81


@dataclass(frozen=True)
class Context:
    """What an effect may use besides its parameters."""

    mass: float
    a: float
    b: float
    vx: float  # m/s, the speed of the stretch being simulated

    @property
    def L(self) -> float:
        return self.a + self.b

    def axle_loads(self):
        return self.mass * G * self.b / self.L, self.mass * G * self.a / self.L


class Effect:
    name: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    stage: ClassVar[str] = "output"
    physics: ClassVar[str] = ""
    signature: ClassVar[str] = ""
    # Candidates whose residual signature this effect shares, and the run that tells them apart.
    confused_with: ClassVar[dict] = {}

    def apply(self, sys: LinSys, p: dict, ctx: Context) -> LinSys:
        return sys

    def tyre_options(self, p: dict, ctx: Context) -> dict:
        return {}

    def force_correction(self, alpha_f: np.ndarray, alpha_r: np.ndarray, p: dict, ctx: Context):
        """Nonlinear part of the axle side forces [N], or None for a linear effect."""
        return None

    @property
    def nonlinear(self) -> bool:
        return type(self).force_correction is not Effect.force_correction


_REGISTRY: dict[str, type[Effect]] = {}
_ENTRY_POINTS_LOADED = False


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available by its name (``bicycle+NAME``)."""
    if not cls.name or not cls.name.isidentifier():
        raise ValueError(f"effect {cls.__name__} needs a name that is a Python identifier")
    if cls.stage not in ("input", "tyre", "output"):
        raise ValueError(f"effect {cls.name}: stage must be 'input', 'tyre' or 'output'")
    _REGISTRY[cls.name] = cls
    return cls


def unregister_effect(name: str) -> None:
    _REGISTRY.pop(name, None)


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    import stid.effects  # noqa: F401  (the built-in catalogue registers itself)

    for ep in entry_points(group="stid.effects"):
        cls = ep.load()
        if isinstance(cls, type) and issubclass(cls, Effect) and cls.name not in _REGISTRY:
            register_effect(cls)


def available_effects() -> dict[str, type[Effect]]:
    _load_entry_points()
    return dict(_REGISTRY)


def get_effect(name: str) -> type[Effect]:
    effects = available_effects()
    if name not in effects:
        raise InputError(f"unknown effect {name!r}; known effects: {', '.join(sorted(effects))}")
    return effects[name]
