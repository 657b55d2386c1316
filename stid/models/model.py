"""A model is a base plus effects, written ``bicycle+effect+effect`` (one word
per effect on the command line, one line in Python: ``Model("bicycle+actuator_lag",
vehicle)``)."""

from __future__ import annotations

import numpy as np

from stid import sensor_chain
from stid.errors import InputError
from stid.models.bicycle import BASE_PARAMS, bicycle
from stid.models.effect import Context, get_effect
from stid.models.linsys import LinSys, foh_input
from stid.models.params import Param

BASES = ("bicycle",)  # "greybox" (study 2) is fitted by stid.fit.greybox_fit
MEASURED = ("ay", "r")
_STAGE_ORDER = {"input": 0, "tyre": 1, "body": 2, "output": 3}
# Passes of the iterated tyre force (Model.simulate). Near a friction limit the iteration can
# creep for a hundred passes and then converge in a few dozen (measured on a tanh-tyre bicycle at
# 0.6 g: 220 passes at the truth, its error down 10-30% every 20 of them); 80 passes, the old
# limit, left such fits at their start. Past ITER_STILL_GAINING passes it goes on only while the
# last ITER_WINDOW passes did better than all before them: where the model car slides out, the
# error wanders between the same values for hundreds of passes.
MAX_ITER = 400
ITER_STILL_GAINING = 80
ITER_WINDOW = 40


def parse_model_name(name: str) -> tuple[str, list[str]]:
    raw = [s.strip() for s in name.split("+")]
    parts = [s for s in raw if s]
    if not parts:
        raise InputError("empty model name; write e.g. 'bicycle' or 'bicycle+actuator_lag'")
    if len(parts) != len(raw):
        raise InputError(f"model {name!r} has an empty part between its '+' signs: name an effect after each "
                         "'+' (e.g. 'bicycle+actuator_lag'; 'stid --help' lists the effects)")
    base, effects = parts[0], parts[1:]
    if base not in BASES:
        if base.startswith("greybox"):
            raise InputError(f"{base!r} (study 2's grey-box) is fitted by 'stid fit --model {base}' only; "
                             "diagnose, compare, report and plan work on the bicycle and its effects")
        from difflib import get_close_matches

        from stid.models.effect import available_effects

        if base in available_effects():
            raise InputError(f"{base!r} is an effect, not a base model: a model starts with the base, "
                             f"e.g. 'bicycle+{'+'.join(parts)}'")
        near = get_close_matches(base, list(BASES) + ["greybox"], n=1)
        raise InputError(f"unknown base model {base!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                         + ": a model is 'bicycle' or 'bicycle+' and its effects (e.g. 'bicycle+actuator_lag'), "
                         "or study 2's 'greybox' or 'greybox-study' (stid fit only)")
    if len(set(effects)) != len(effects):
        raise InputError(f"model {name!r} names an effect twice")
    return base, effects


class Model:
    """A composed single-track model.

    Parameters
    ----------
    name : str
        ``bicycle`` or ``bicycle+effect+...``.
    vehicle : Vehicle
        Supplies mass, a, b [kg, m] and scales the parameter defaults.
    """

    def __init__(self, name: str, vehicle):
        self.base, names = parse_model_name(name)
        self.effects = [get_effect(n)() for n in names]
        self.vehicle = vehicle
        self.params: list[Param] = list(BASE_PARAMS)
        seen = {p.name: "bicycle" for p in self.params}
        for e in self.effects:
            for p in e.params:
                if p.name in seen:
                    raise InputError(f"effects {seen[p.name]} and {e.name} both define parameter {p.name!r}")
                seen[p.name] = e.name
                self.params.append(p)
        self._ordered = sorted(self.effects, key=lambda e: _STAGE_ORDER[e.stage])
        # The steering chain as on the car: command -> servo (its lag, its trim) -> linkage -> wheels.
        # Maps at the servo's place act on the command (a trim: a constant passes a unit-gain lag
        # unchanged); a linkage's map takes the servo's output, so where the model has one, the
        # servo's linear blocks are run on the sampled steer before it (Model.simulate) and left out
        # of the linear model the rest is simulated with (build(..., servo_apart=True)).
        maps = [e for e in self._ordered if e.maps_steer]
        self._servo_maps = [e for e in maps if e.steer_place == "servo"]
        self._linkage_maps = [e for e in maps if e.steer_place == "linkage"]
        self._servo_blocks = [e for e in self._ordered if e.stage == "input" and not e.maps_steer
                              and e.steer_place == "servo"] if self._linkage_maps else []
        # the catalogue's effects keep the single track's speed law (tests/test_effects_contract.py):
        # the LPV simulator need not check it on every parameter set; a user's effect is checked
        self._law_known = all(type(e).__module__.startswith("stid.effects.") for e in self.effects)
        self._warm: dict = {}  # last converged force correction per steer history (nonlinear effects)
        self._laws: dict = {}  # speed laws of the last few parameter sets (stid.models.lpv.SpeedLaw)
        self.converged = True
        # The sensors' output filters are part of the measurement, not effects to discover.
        # They come with the data (stid.sensor_chain; a stretch passes its own chain to
        # simulate/build); this default is the vehicle file's [sensors], else none.
        chain = sensor_chain.from_vehicle(vehicle)
        self.sensor_bandwidth = {k: v for k, v in chain.items() if k != "source"}
        if not self._law_known:
            self._try_users_effects()

    def _try_users_effects(self) -> None:
        """A user's effect, tried once at the defaults before any data work: an error in its
        code is named with its file here, not met as a traceback (or as a fit that 'failed
        numerically') in the middle of a diagnosis."""
        import sys

        from stid.errors import StidError

        mine = [e for e in self.effects if not type(e).__module__.startswith("stid.effects.")]

        def where(e):
            return f"{e.name} ({getattr(sys.modules.get(type(e).__module__), '__file__', None) or type(e).__module__})"

        try:
            p, ctx = self.defaults(), self.context(5.0)
            for e in mine:
                for q in e.params:
                    self.bounds(q.name)
        except StidError:
            raise
        except Exception as ex:  # (a bound or start that is no number: None, a string)
            raise InputError(f"your effect {', '.join(where(e) for e in mine)}: a parameter's start or bounds are "
                             f"not numbers ({type(ex).__name__}: {ex}): give each Param numbers, or functions of "
                             "the vehicle that return them") from None
        try:
            self.build(p, ctx.vx)
            for e in self._ordered:
                if e.maps_steer:
                    e.steer_map(np.zeros(4), p, ctx)
        except StidError:
            raise
        except Exception as ex:
            raise InputError(f"your effect {', '.join(where(e) for e in mine)} fails when the model {self.name} is "
                             f"built at its defaults ({type(ex).__name__}: {ex}): fix it (docs/writing_an_effect.md "
                             "lists what each stage's method may do)") from None
        for e in mine:
            for q in e.params:  # (the contract the catalogue's effects are tested for, on the user's own)
                lo, hi = self.bounds(q.name)
                if not q.unit.strip():
                    raise InputError(f"your effect {where(e)}: parameter {q.name} has no unit: give it one (SI; "
                                     "'1' for a pure number): it is printed with every value")
                if not (np.isfinite(lo) and np.isfinite(hi) and lo <= p[q.name] <= hi):
                    raise InputError(f"your effect {where(e)}: parameter {q.name} starts at {p[q.name]!r}, outside "
                                     f"its bounds [{lo!r}, {hi!r}]: give finite bounds that hold the start")
            if not e.maps_steer and not e.nonlinear and not any(self._moves(e, p, v) for v in (2.0, 5.0, 8.0)):
                raise InputError(f"your effect {where(e)}: changing its parameters ({', '.join(q.name for q in e.params)}) "
                                 f"changes nothing in the model: is its stage ({e.stage!r}) the one whose method it "
                                 "defines ('body' for body_loads, 'tyre' for tyre_options, 'input' or 'output' for "
                                 "apply; docs/writing_an_effect.md)?")

    def _moves(self, e, p: dict, vx: float) -> bool:
        """Whether the linear model's responses change with any of effect ``e``'s parameters (at
        ``vx``, from the values ``p``, each moved a tenth of the way to a bound)."""
        f = np.array([0.2, 1.0, 4.0])

        def response(q):  # (the offsets too: a sensor offset is a constant the frequency response leaves out)
            return self.freqresp(q, f, vx), dict(self.build(q, vx).offsets)

        base, base_off = response(p)
        for q in e.params:
            lo, hi = self.bounds(q.name)
            for to in (hi, lo):
                moved = dict(p, **{q.name: p[q.name] + 0.1 * (to - p[q.name])})
                if moved[q.name] == p[q.name]:
                    continue
                resp, off = response(moved)
                if not np.allclose(resp, base, rtol=1e-9, atol=1e-12) or off != base_off:
                    return True
        return not e.params

    @property
    def name(self) -> str:
        return "+".join([self.base] + [e.name for e in self.effects])

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)

    def defaults(self) -> dict:
        return {p.name: p.value("init", self.vehicle) for p in self.params}

    def bounds(self, name: str):
        p = self.param(name)
        return p.value("lower", self.vehicle), p.value("upper", self.vehicle)

    def at_bound(self, name: str, value: float, tol: float = 1e-3) -> bool:
        """Whether ``value`` of parameter ``name`` sits within ``tol`` of its range's span from
        an end (the span in log for a log parameter): the data pushed it, or nothing held it."""
        lo, hi = self.bounds(name)
        if self.param(name).log:
            lo, hi, value = np.log(lo), np.log(hi), np.log(max(value, 1e-300))
        return value - lo < tol * (hi - lo) or hi - value < tol * (hi - lo)

    def at_vanishing_end(self, name: str, value: float) -> bool:
        """Whether ``value`` sits at the end of ``name``'s range beyond which its effect vanishes
        (the parameter's ``zero`` at or past that bound: a lag's or a relaxation length's lower end)."""
        zero = self.param(name).zero
        if zero is None:
            return False
        lo, hi = self.bounds(name)
        return (zero <= lo and abs(value - lo) <= abs(value - hi)) or (zero >= hi and abs(value - hi) < abs(value - lo))

    def owner(self, name: str) -> str:
        for e in self.effects:
            if any(p.name == name for p in e.params):
                return e.name
        return "bicycle"

    def context(self, vx: float) -> Context:
        v = self.vehicle
        return Context(mass=v.mass, a=v.a, b=v.b, vx=float(vx))

    @property
    def nonlinear(self) -> bool:
        return any(e.nonlinear for e in self.effects)

    def build(self, p: dict, vx: float, sensors: dict | None = None, servo_apart: bool = False):
        """The linear(ised) state-space system at speed vx, its ay and r outputs passed
        through the sensor chain ``sensors`` ({"ay": Hz, "r": Hz}, 0 = no filter; default
        the model's own). ``servo_apart``: without the servo's linear blocks, for a steer
        that has been through them and the linkage already (Model.simulate). Linearised at
        straight running, where a linkage's map has slope 1, the order of the two does not
        matter: the frequency response and the planner take the whole chain from here."""
        ctx = self.context(vx)
        opts = {}
        for e in self._ordered:
            if e.stage == "tyre":
                opts.update(e.tyre_options(p, ctx))
        loads = [e.body_loads(p, ctx) for e in self._ordered if e.stage == "body"]
        sys = bicycle(p, ctx, loads=loads, **opts)
        for e in self._ordered:
            if e.stage in ("input", "output") and not (servo_apart and e in self._servo_blocks):
                sys = e.apply(sys, p, ctx)
        chain = self.sensor_bandwidth if sensors is None else sensors
        for out in MEASURED:
            f = float(chain.get(out, 0.0) or 0.0)
            if 0 < f < float("inf"):
                sys = sys.filter_output(out, f, sensor_chain.order(chain, out))
        return sys

    def freqresp(self, p: dict, f_hz: np.ndarray, vx: float, sensors: dict | None = None) -> np.ndarray:
        """Responses of (ay, r) to steer at f_hz, linearised at straight running: (2, n_f)."""
        return self.build(p, vx, sensors).select(list(MEASURED)).freqresp(f_hz)

    def simulator(self, p: dict, vx, dt: float, outputs, inputs, sensors: dict | None = None,
                  servo_apart: bool = False):
        """``sim(u) -> y`` for inputs u (n_t, len(inputs)) sampled at dt.

        ``vx`` is one speed [m/s] (a linear time-invariant system, filtered by scipy) or
        the measured speed at every sample (a linear parameter-varying system,
        ``stid.models.lpv``): a run need not hold its speed. ``servo_apart`` as in build.
        """
        v = np.asarray(vx, float)
        if v.ndim == 0 or (len(v) and np.ptp(v) == 0.0):
            v0 = float(v) if v.ndim == 0 else float(v[0])
            return self.build(p, v0, sensors, servo_apart).simulator(dt, list(outputs), list(inputs))
        from stid.models.lpv import LpvSimulator

        def build(s):
            return self.build(p, s, sensors, servo_apart)

        return LpvSimulator(build, v, dt, outputs, inputs, law=self._law(p, outputs, inputs, sensors, servo_apart))

    def _law(self, p: dict, outputs, inputs, sensors, servo_apart: bool):
        """The speed law of the system ``p`` builds (stid.models.lpv.SpeedLaw). One evaluation
        simulates the same parameters on every stretch: the law (three builds and a check) is
        found once for all of them."""
        from stid.models.lpv import SpeedLaw, system_parts

        key = (tuple(sorted(p.items())), tuple(sorted((sensors or {}).items())), tuple(outputs), tuple(inputs),
               servo_apart)
        law = self._laws.get(key)
        if law is None:
            law = SpeedLaw(system_parts(lambda s: self.build(p, s, sensors, servo_apart), outputs, inputs),
                           check=not self._law_known)
            if len(self._laws) >= 8:
                self._laws.pop(next(iter(self._laws)))
            self._laws[key] = law
        return law

    def _servo_output(self, p: dict, steer: np.ndarray, dt: float, v: np.ndarray) -> np.ndarray:
        """The servo's output for the logged steer: the linear blocks at the servo's place on
        the steering chain (its lag) run on the sampled command, for the linkage to take. A lag
        of a sampled band-limited signal is exact, and costs one state's recursion."""

        def build(s):
            sys = LinSys(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1)), [], ["delta"],
                         ["delta"])
            for e in self._servo_blocks:
                sys = e.apply(sys, p, self.context(s))
            return sys

        if v.ndim == 0 or (len(v) and np.ptp(v) == 0.0):
            sim = build(float(v) if v.ndim == 0 else float(v[0])).simulator(dt, ["delta"], ["delta"])
        else:
            from stid.models.lpv import LpvSimulator

            sim = LpvSimulator(build, v, dt, ["delta"], ["delta"])
        return sim(foh_input(steer), u_out=steer)[:, 0]

    def _steer_chain(self, p: dict, steer, dt: float, v: np.ndarray):
        """The steer as the rest of the model takes it: through the static maps (exact, on the
        sampled signal) and the servo's lag where the model runs it apart, in the steering
        chain's order. Returns it, whether the servo was run apart, and the context at the run's
        median speed (None where nothing needs it)."""
        # the context is for the steer maps and the tyre forces only: a linear model without maps
        # never needs it (the median costs as much as the build)
        maps = self._servo_maps + self._linkage_maps
        ctx = self.context(float(np.median(v)) if v.ndim else float(v)) if maps or self.nonlinear else None
        steer = np.asarray(steer, float)
        for e in self._servo_maps:
            steer = np.asarray(e.steer_map(steer, p, ctx), float)
        apart = bool(self._servo_blocks)
        if apart:
            steer = self._servo_output(p, steer, dt, v)
        for e in self._linkage_maps:
            steer = np.asarray(e.steer_map(steer, p, ctx), float)
        return steer, apart, ctx

    def simulate_many(self, ps: list, steer: np.ndarray, dt: float, vx, outputs=MEASURED,
                      sensors: dict | None = None) -> list:
        """``[self.simulate(p, steer, dt, vx, outputs, sensors=sensors) for p in ps]``: parameter
        sets a little apart (a forward-difference Jacobian's columns) on one stretch. A linear
        model at a measured speed discretises them all in one batch (stid.models.lpv.LpvSimulator.
        many): a simulation is a few hundred microseconds of Python and numpy calls on small
        matrices around a compiled recursion of a hundred, and a batch shares most of them."""
        v = np.asarray(vx, float)
        if self.nonlinear or len(ps) < 2 or v.ndim == 0 or (len(v) and np.ptp(v) == 0.0):
            return [self.simulate(p, steer, dt, vx, outputs, sensors=sensors) for p in ps]
        from stid.models.lpv import LpvSimulator

        outs = list(outputs)
        chains = [self._steer_chain(p, steer, dt, v) for p in ps]
        laws = [self._law(p, outs, ["delta"], sensors, apart) for p, (_, apart, _) in zip(ps, chains)]
        if not all(law.ok for law in laws):  # (a user's effect with another speed law: one by one)
            return [self.simulate(p, steer, dt, vx, outputs, sensors=sensors) for p in ps]
        sims = LpvSimulator.many(laws, v, dt)
        return [sim(foh_input(s), u_out=s) for sim, (s, _, _) in zip(sims, chains)]

    def simulate(self, p: dict, steer: np.ndarray, dt: float, vx, outputs=MEASURED,
                 max_iter: int = MAX_ITER, tol: float = 1e-9, sensors: dict | None = None) -> np.ndarray:
        """Measured outputs for a steer history (n_t,): (n_t, len(outputs)).

        ``vx`` is a constant speed or the speed at every sample [m/s]. The steer goes
        through the steering chain as on the car: the servo (its trim, its lag), then the
        linkage's map, then the rest of the model. Linear models
        are one vectorised filter pass (constant speed) or one compiled time-varying
        recursion (varying speed). With a nonlinear tyre effect the
        whole trajectory is iterated (waveform relaxation): simulate, compute the force
        correction from the slip angles, simulate again with it as an input. Anderson
        acceleration makes that converge in a few passes, and the last solution for the
        same steer history is the starting guess (an optimiser's next evaluation differs
        only slightly). Where it does not converge (the model car would slide out),
        the last iterate is returned and ``self.converged`` is False: its poor fit
        steers the optimiser away.
        """
        v = np.asarray(vx, float)
        steer, apart, ctx = self._steer_chain(p, steer, dt, v)
        # the simulators hold the input first-order: the states are driven by samples whose
        # chords carry the band-limited signal (linsys.foh_input); an output that feeds the
        # steer straight through (no sensor filter) takes the sample itself
        held = foh_input(steer)
        if not self.nonlinear:
            sim = self.simulator(p, vx, dt, list(outputs), ["delta"], sensors, apart)
            return sim(held, u_out=steer)
        outs = list(outputs)
        n = len(steer)
        # the steer's part is fixed; each pass only needs the slip angles' response
        # to the force correction
        sim = self.simulator(p, vx, dt, outs + ["alpha_f", "alpha_r"], ["delta", "dFf", "dFr"], sensors, apart)
        zeros = np.zeros(n)
        base = sim(np.column_stack([held, zeros, zeros]), u_out=np.column_stack([steer, zeros, zeros]))
        no = len(outs)

        def slip_of_force(f):
            return sim(np.column_stack([zeros, f]))[:, no:]

        Fzf, Fzr = ctx.axle_loads()
        scale = tol * min(Fzf, Fzr)
        key = (n, float(steer[0]), float(steer[n // 2]), float(v.ravel()[0]), float(v.ravel()[-1]))
        x = self._warm.get(key)
        x = np.zeros(2 * n) if x is None else x.copy()

        def g(xv):
            a = base[:, -2:] + slip_of_force(xv.reshape(n, 2))
            new = np.zeros((n, 2))
            for e in self.effects:
                c = e.force_correction(a[:, 0], a[:, 1], p, ctx)
                if c is not None:
                    new += np.column_stack(c)
            return new.ravel()

        X, R, sizes = [], [], []
        self.converged = False
        for k in range(max_iter):
            gx = g(x)
            r = gx - x
            sizes.append(float(np.max(np.abs(r))))
            if sizes[-1] < scale:
                self.converged = True
                break
            if k >= ITER_STILL_GAINING and min(sizes[-ITER_WINDOW:]) > 0.9 * min(sizes[:-ITER_WINDOW]):
                break  # no better in the last ITER_WINDOW passes: it wanders (the model car slides out)
            X.append(x.copy())
            R.append(r)
            X, R = X[-7:], R[-7:]
            if len(R) > 1:
                dR = np.diff(np.array(R), axis=0)  # (m, 2n): a few long rows
                dX = np.diff(np.array(X), axis=0)
                M = dR @ dR.T
                gamma = np.linalg.solve(M + 1e-12 * np.trace(M) * np.eye(len(M)), dR @ r)
                x = x + r - gamma @ (dX + dR)
            else:
                x = x + r
        # finish with the newest correction: under a warm start this keeps the
        # result differentiable in the parameters
        x = gx
        if self.converged:
            self._warm[key] = x
        return base[:, :no] + sim(np.column_stack([zeros, x.reshape(n, 2)]))[:, :no]
