"""The seam for physical effects: a small base class, a registry, and entry points.

An effect changes the single-track model at one of four places, in this order:

- ``"input"``: the steering path before the tyres. ``apply`` returns the system
  with a linear block in front of the ``delta`` input (servo lag, a Pade delay);
  a static nonlinear map (linkage geometry) implements ``steer_map`` instead,
  which the model applies to the sampled steer signal (exact: no iteration, the
  rest of the model stays linear). ``steer_place`` says where on the car's
  steering chain the effect sits: ``"servo"`` (the servo's dynamics and its trim)
  or ``"linkage"`` (horn, tie rods, steering arms: driven by the servo's output).
  A map at ``"linkage"`` takes the output of the linear blocks at ``"servo"``, as
  on the car: the model runs those blocks on the sampled steer first
  (``stid.models.model.Model.simulate``).
- ``"tyre"``: how side forces build up. ``tyre_options`` returns options for the
  base model (relaxation lengths); a nonlinear tyre effect implements
  ``force_correction`` (force minus its linear part, from the slip angles).
- ``"body"``: forces and moments on the body that are not tyre side forces (a
  locked differential's yaw moment, aerodynamics). ``body_loads`` returns a
  ``BodyLoad``: an extra lateral force Fy [N] and yaw moment Mz [N m], each a
  linear combination of the base model's states ``vy`` [m/s], ``r`` [rad/s] and
  its input ``delta`` [rad], with coefficients that may depend on the parameters
  and the speed ``ctx.vx``. The base model adds them to its body equations

      m (vy' + vx r) = Fyf + Fyr + Fy,      Iz r' = a Fyf - b Fyr + Mz,

  so the accelerometer (ay = (Fyf + Fyr + Fy)/m), the yaw acceleration and every
  later stage see them, and no effect edits ``sys.A`` by hand. The model is still
  assembled as one linear system at each speed, so the frequency fit, the
  Cramer-Rao planner and the measured-speed (LPV) simulator, which rebuilds the
  matrices at several speeds and fits c0 + c1 vx + c2/vx per entry, use it
  unchanged (a coefficient with another speed law is built at every grid speed).
- ``"output"``: what the sensors see (offsets, tilt, mounting position).
  ``apply`` adds states or changes the ``ay`` / ``r`` output rows.

A new effect is one class with ``name``, ``params``, ``stage``, ``physics`` (one
paragraph), ``signature`` (how it shows in the residuals) and the method for its
stage, registered with ``@register_effect``, through the ``stid.effects`` entry
point group, or from a Python file named in the ``STID_EFFECTS`` environment
variable (paths separated by ``os.pathsep``; for trying an effect before it is
packaged). The contract tests and ``stid diagnose`` pick it up with no other
change. See docs/writing_an_effect.md.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import ClassVar

from stid.lazy_numpy import np

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


BODY_SIGNALS = ("vy", "r", "delta")  # what a body load may be a linear function of


@dataclass(frozen=True)
class BodyLoad:
    """Extra lateral force and yaw moment on the body, linear in the base model's signals.

    Parameters
    ----------
    Fy : dict
        Coefficients of the lateral force [N] on ``vy`` [N s/m], ``r`` [N s/rad] and
        ``delta`` [N/rad] (missing keys are 0).
    Mz : dict
        Coefficients of the yaw moment [N m] on the same signals [N m s/m, N m s/rad, N m/rad].
    """

    Fy: dict = field(default_factory=dict)
    Mz: dict = field(default_factory=dict)

    def __post_init__(self):
        for what, coef in (("Fy", self.Fy), ("Mz", self.Mz)):
            bad = set(coef) - set(BODY_SIGNALS)
            if bad:
                raise ValueError(f"a body load's {what} can depend on {', '.join(BODY_SIGNALS)} only, "
                                 f"not {', '.join(sorted(bad))}")


class Effect:
    name: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    stage: ClassVar[str] = "output"
    physics: ClassVar[str] = ""
    signature: ClassVar[str] = ""
    # Candidates whose residual signature this effect shares, and the run that tells them apart.
    confused_with: ClassVar[dict] = {}
    # Stage "input": the effect's place on the steering chain, from the logged command to the road
    # wheels. "servo": the servo's own dynamics and its trim, which act on the command. "linkage":
    # what the servo's output drives (horn, tie rods, arms); a steer map here takes the servo's
    # output, not the command. A linear block at "linkage" (or a pure delay, which commutes with a
    # static map) stays in the linear model, behind every map.
    steer_place: ClassVar[str] = "linkage"
    # Said under every fit of a model with this effect: what the effect's form assumes that a car
    # need not do, and what that does to the numbers beyond their intervals (empty: nothing).
    fit_note: ClassVar[str] = ""

    def apply(self, sys: LinSys, p: dict, ctx: Context) -> LinSys:
        return sys

    def tyre_options(self, p: dict, ctx: Context) -> dict:
        return {}

    def force_correction(self, alpha_f: np.ndarray, alpha_r: np.ndarray, p: dict, ctx: Context):
        """Nonlinear part of the axle side forces [N], or None for a linear effect."""
        return None

    def body_loads(self, p: dict, ctx: Context) -> BodyLoad:
        """Stage ``"body"``: the extra lateral force and yaw moment (see ``BodyLoad``)."""
        return BodyLoad()

    def steer_map(self, delta_cmd: np.ndarray, p: dict, ctx: Context) -> np.ndarray:
        """Stage ``"input"``, nonlinear: the road-wheel angle [rad] for the logged steer [rad],
        a static map applied to every sample (its slope at 0 should be 1: the steering
        calibration fixes the small-angle gain, which Cf cannot tell from a gain error)."""
        return delta_cmd

    @property
    def nonlinear(self) -> bool:
        """Needs the iterated simulation (a force that depends on the slip angles)."""
        return type(self).iterated()

    @classmethod
    def iterated(cls) -> bool:
        """``nonlinear``, asked of the class (before any model is built with it)."""
        return cls.force_correction is not Effect.force_correction

    @property
    def maps_steer(self) -> bool:
        """Changes the steer signal by a static nonlinear map (exact, not iterated)."""
        return type(self).steer_map is not Effect.steer_map


STAGES = ("input", "tyre", "body", "output")  # the order in which a model applies them
STEER_PLACES = ("servo", "linkage")  # an input effect's place on the steering chain, command first
_REGISTRY: dict[str, type[Effect]] = {}
_ENTRY_POINTS_LOADED = False


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available by its name (``bicycle+NAME``)."""
    if not cls.name or not cls.name.isidentifier():
        raise ValueError(f"effect {cls.__name__} needs a name that is a Python identifier")
    if cls.stage not in STAGES:
        raise ValueError(f"effect {cls.name}: stage must be one of {', '.join(map(repr, STAGES))}")
    if cls.steer_place not in STEER_PLACES:
        raise ValueError(f"effect {cls.name}: steer_place must be one of {', '.join(map(repr, STEER_PLACES))}")
    there = _REGISTRY.get(cls.name)
    if there is not None and (there.__module__, there.__qualname__) != (cls.__module__, cls.__qualname__):
        # (the same class loaded again, a module reloaded, is not a clash)
        raise ValueError(f"an effect named {cls.name!r} already exists ({there.__module__}.{there.__qualname__}): "
                         f"give {cls.__qualname__} another name")
    if not cls.__module__.startswith("stid.effects."):
        _guard_hooks(cls)
    _REGISTRY[cls.name] = cls
    return cls


HOOKS = ("apply", "tyre_options", "body_loads", "force_correction", "steer_map")


def _finite(x) -> bool:
    """Whether what a hook returned holds no nan or inf (a system, a body load, options, arrays)."""
    if x is None:
        return True
    if isinstance(x, BodyLoad):
        return all(np.isfinite(float(v)) for d in (x.Fy, x.Mz) for v in d.values())
    if isinstance(x, dict):
        return all(_finite(v) for v in x.values())
    if isinstance(x, (tuple, list)):
        return all(_finite(v) for v in x)
    if hasattr(x, "A") and hasattr(x, "D"):  # a LinSys
        return all(np.all(np.isfinite(m)) for m in (x.A, x.B, x.C, x.D))
    try:
        return bool(np.all(np.isfinite(np.asarray(x, float))))
    except (TypeError, ValueError):
        return True


def _guard_hooks(cls) -> None:
    """A user's effect's methods, each wrapped so that an exception in it, or a nan or inf it
    returns, ends in one line naming the effect, its file, the method, the speed and the
    parameters (a trial user's raised at 5.5 m/s only, past the check at the defaults, and came
    out as a traceback, or as 'Array must not contain infs or NaNs' from deep in a fit)."""
    import functools

    from stid.errors import StidError

    for hook in HOOKS:
        fn = cls.__dict__.get(hook)
        if fn is None or getattr(fn, "_stid_guarded", False):
            continue

        def guarded(self, *args, _fn=fn, _hook=hook):
            ctx = next((a for a in args if isinstance(a, Context)), None)
            p = next((a for a in args if isinstance(a, dict)), {})
            try:
                out = _fn(self, *args)
            except StidError:
                raise
            except Exception as e:
                raise InputError(_hook_words(self, _hook, ctx, p, f"raised {type(e).__name__}: {e}")) from None
            if not _finite(out):
                raise InputError(_hook_words(self, _hook, ctx, p, "returned nan or inf"))
            return out

        guarded._stid_guarded = True
        setattr(cls, hook, functools.wraps(fn)(guarded))


def _hook_words(effect, hook, ctx, p, what) -> str:
    own = {q.name: p.get(q.name) for q in effect.params if q.name in p}
    source = getattr(sys.modules.get(type(effect).__module__), "__file__", None) or type(effect).__module__
    at = f" at vx = {ctx.vx:.3g} m/s" if ctx is not None else ""
    return (f"your effect {effect.name} ({source}): its {hook}() {what}{at} with "
            + (", ".join(f"{k} = {v:.4g}" for k, v in own.items()) or "no parameters")
            + ": it must give finite values at every forward speed (the model is built at speeds around the "
              "runs') and every parameter value within its bounds (docs/writing_an_effect.md)")


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
    for path in filter(None, os.environ.get("STID_EFFECTS", "").split(os.pathsep)):
        _load_effect_file(Path(path))


def _load_effect_file(path: Path) -> None:
    """Run a user's effect module (its ``@register_effect`` classes register themselves)."""
    import importlib.util

    if not path.is_file():
        raise InputError(f"STID_EFFECTS names {path}, which is not a file: give the path of the Python "
                         "file that defines your effect")
    spec = importlib.util.spec_from_file_location(f"stid_user_effect_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (as an import would: its classes can say which file they are from)
    before = set(_REGISTRY)
    try:
        spec.loader.exec_module(module)
    except Exception as e:  # the user's code: say where, in one line
        sys.modules.pop(spec.name, None)
        raise InputError(f"STID_EFFECTS: {path} failed to load ({type(e).__name__}: {e}); fix the file "
                         "or remove it from STID_EFFECTS") from None
    if set(_REGISTRY) == before and not any(getattr(c, "__module__", None) == spec.name for c in _REGISTRY.values()):
        # (diagnose then told a trial user to write an effect the catalogue lacks, as if theirs had failed)
        truth = any(hasattr(module, f) for f in ("sensor_signals", "body_loads", "steer_angle"))
        raise InputError(f"STID_EFFECTS: {path} registers no effect: decorate its Effect class with "
                         "@register_effect (docs/writing_an_effect.md)"
                         + ("; it looks like a simulator's truth-side file, which is for stid-sim --effect-file"
                            if truth else ""))


def available_effects() -> dict[str, type[Effect]]:
    _load_entry_points()
    return dict(_REGISTRY)


def get_effect(name: str) -> type[Effect]:
    effects = available_effects()
    if name not in effects:
        from difflib import get_close_matches

        near = get_close_matches(name, list(effects), n=1)
        raise InputError(f"unknown effect {name!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                         + f"; known effects: {', '.join(sorted(effects))}")
    return effects[name]
