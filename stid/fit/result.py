"""The result of a fit: values with standard errors, 95% intervals and the
correlation matrix, fit percent per output, information criteria and warnings.
The numbers live here; ``table()`` and ``to_json()`` only present them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import stdtrit  # Student t quantile (scipy.stats is slow to import)

OUTPUT_UNITS = {"ay": "m/s^2", "r": "rad/s"}


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB-style fit: 100 (1 - ||y - yhat|| / ||y - mean(y)||); nan for an output that does
    not vary (a constant steer on a circle: its spread is round-off, and the ratio meaningless)."""
    den = np.linalg.norm(y - np.mean(y))
    if den <= 1e-9 * np.linalg.norm(y):
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den))


# A delay the data show beyond the model's below this is not worth an effect: it moves the
# parameters by less than the intervals allow for, and a speed's or a filter's timing makes one.
DELAY_WORTH_MS = 1.0


@dataclass
class Prediction:
    """Measured and modelled outputs on one stretch (kept for compare, diagnose, report)."""

    name: str
    t: np.ndarray
    steer: np.ndarray
    y: np.ndarray  # (n, 2): ay, r
    yhat: np.ndarray
    vx: float
    keep: np.ndarray  # samples used in the cost (start-up transient excluded)


@dataclass
class FitResult:
    model: str
    method: str
    names: list
    values: np.ndarray
    cov: np.ndarray
    units: dict
    owners: dict = field(default_factory=dict)  # parameter -> component ("bicycle" or effect)
    fixed: dict = field(default_factory=dict)  # name -> (value, unit, why)
    fit: dict = field(default_factory=dict)  # output -> percent
    n: int = 0  # residuals in the likelihood
    loglik: float = float("nan")
    warnings: list = field(default_factory=list)
    notes: list = field(default_factory=list)  # what the data selection left out, what was assumed
    interval: str = ""  # which kind of 95% interval ci95 is (noise only, or with model error)
    ci_dof: int | None = None  # degrees of freedom of the interval's t quantile (default n - k)
    ci_allowance: np.ndarray | None = None  # model-error allowance added to each half-width (the geometry)
    # and for a delay between the steer and the outputs that the model leaves out (stid.fit.intervals)
    delay_allowance: np.ndarray | None = None
    # the gyro zero's own uncertainty (stid.fit.intervals.gyro_zero_allowance), added to each half-width
    zero_allowance: np.ndarray | None = None
    positive: tuple = ()  # parameters positive by nature (a stiffness, an inertia, a lag): see ci95
    predictions: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)  # method-specific (steady-state line fits, FRFs)
    # whether the numbers are an optimum (stid.fit.convergence): the solver's words, the parameters
    # on a bound, and those the data do not determine (name -> why), which get no interval
    converged: bool = True
    status: str = ""
    at_bound: tuple = ()
    verdict_undetermined: dict = field(default_factory=dict)  # the solve's verdict: name -> why (see undetermined)

    # -- numbers ------------------------------------------------------------
    @property
    def stderr(self) -> np.ndarray:
        """Standard errors; nan for a parameter the data do not determine (a zero from a
        rank-deficient covariance, or one at a failed optimum, is no standard error)."""
        se = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        return np.where(self.determined, se, np.nan)

    @property
    def determined(self) -> np.ndarray:
        """Per parameter: the data determine it (it has an interval)."""
        return np.array([n not in self.undetermined for n in self.names], bool)

    def set_verdict(self, verdict) -> None:
        """Take a solve's verdict (stid.fit.convergence.Verdict)."""
        self.converged, self.status = bool(verdict.converged), verdict.status
        self.at_bound = tuple(verdict.at_bound)
        self.verdict_undetermined = dict(verdict.undetermined)

    @property
    def undetermined(self) -> dict:
        """Parameters with no interval, and why: the solve's verdict (not converged, at a bound,
        rank-deficient), and a positive parameter whose interval spans more than a factor of
        MAX_SPAN (its log-space half-width: it says nothing of the value, and overflows)."""
        out = dict(self.verdict_undetermined)
        if self.positive and len(self.values):
            half = self._half95(np.sqrt(np.maximum(np.diag(self.cov), 0.0)))  # (not stderr: it asks this)
            for i, n in enumerate(self.names):
                if n in self.positive and self.values[i] > 0 and not 2 * half[i] / self.values[i] < math.log(MAX_SPAN):
                    out.setdefault(n, f"its interval would span more than a factor of {MAX_SPAN:g}")
        return out

    @undetermined.setter
    def undetermined(self, value: dict) -> None:
        self.verdict_undetermined = dict(value)

    def interval_of(self, name: str):
        """(lo, hi) of the parameter's 95% interval, or None when the data do not determine it."""
        if name in self.undetermined or name not in self.names:
            return None
        lo, hi = self.ci95[self.names.index(name)]
        return float(lo), float(hi)

    @property
    def half95(self) -> np.ndarray:
        """Each 95% interval's half-width, as its kind makes it (t quantile times the standard
        error, plus any allowance): what a test of two values against their intervals takes.
        nan where the data do not determine the parameter."""
        return self._half95(self.stderr)

    @property
    def half95_between_groups(self) -> np.ndarray:
        """The half-widths two fits of one car in other conditions (speeds, amplitudes) are told
        apart by: without the delay allowance. One dead time is in both and moves both alike; the
        allowance for it made every stand-in effect's parameter look like one value across
        speeds (a tutorial's hidden accel_scale was taken for gyro_scale)."""
        return self._half95(self.stderr, delay=False)

    def _half95(self, stderr: np.ndarray, delay: bool = True) -> np.ndarray:
        dof = self.ci_dof if self.ci_dof else max(self.n - len(self.values), 1)
        half = stdtrit(dof, 0.975) * stderr
        if self.ci_allowance is not None:
            half = half + self.ci_allowance
        if self.zero_allowance is not None:
            half = half + self.zero_allowance
        if delay and self.delay_allowance is not None:
            half = half + self.delay_allowance
        return half

    @property
    def ci95(self) -> np.ndarray:
        """(k, 2) rows of 95% intervals; a row of nan where the data do not determine it."""
        return self._ci(self.half95)

    @property
    def ci95_between_groups(self) -> np.ndarray:
        """The intervals of ``half95_between_groups``: what two fits of one car in other
        conditions are compared by, and so what a comparison shows."""
        return self._ci(self.half95_between_groups)

    def _ci(self, half: np.ndarray) -> np.ndarray:
        lo, hi = self.values - half, self.values + half
        # a parameter positive by nature gets the same relative half-width in log space (where the
        # solver fits it): an interval [-1693, 6595] N/rad for a cornering stiffness holds values no
        # car has. Where the half-width is small against the value the two are the same.
        for i, n in enumerate(self.names):
            if n in self.positive and self.values[i] > 0:
                w = half[i] / self.values[i]
                if not 2 * w < math.log(MAX_SPAN):  # no interval (see undetermined)
                    lo[i] = hi[i] = np.nan
                    continue
                lo[i], hi[i] = self.values[i] * np.exp(-w), self.values[i] * np.exp(w)
        return np.column_stack([lo, hi])

    @property
    def corr(self) -> np.ndarray:
        s = self.stderr
        with np.errstate(invalid="ignore", divide="ignore"):
            c = self.cov / np.outer(s, s)
        return np.where(np.isfinite(c), c, 0.0)

    @property
    def k(self) -> int:
        return len(self.values)

    @property
    def aic(self) -> float:
        return 2 * self.k - 2 * self.loglik

    @property
    def bic(self) -> float:
        return self.k * math.log(max(self.n, 1)) - 2 * self.loglik

    def params(self) -> dict:
        return dict(zip(self.names, self.values))

    def all_params(self) -> dict:
        out = {k: v[0] for k, v in self.fixed.items()}
        out.update(self.params())
        return out

    def value(self, name: str) -> float:
        return self.all_params()[name]

    def warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    # -- presentation ------------------------------------------------------
    def params_json(self) -> dict:
        """Each fitted parameter's value, standard error and interval (null where the data do
        not determine it, with why), unit and whether it sits on a bound; held ones with why."""
        params = {}
        for name, v, se, ok in zip(self.names, self.values, self.stderr, self.determined):
            params[name] = {"value": float(v), "stderr": float(se) if ok else None,
                            "ci95": list(self.interval_of(name)) if ok else None,
                            "unit": self.units[name], "at_bound": name in self.at_bound}
            if not ok:
                params[name]["no_interval"] = self.undetermined[name]
        for name, (v, unit, why) in self.fixed.items():
            params[name] = {"value": float(v), "stderr": None, "unit": unit, "fixed": why}
        return params

    def to_json(self) -> dict:
        return {"model": self.model, "method": self.method, "converged": bool(self.converged),
                "status": self.status, "params": self.params_json(),
                "fit": {k: round(float(v), 2) if np.isfinite(v) else None for k, v in self.fit.items()},
                "correlation": {"params": list(self.names), "matrix": np.round(self.corr, 4).tolist()},
                "aic": float(self.aic), "bic": float(self.bic), "n": int(self.n),
                "interval": self.interval, **self._delay_json(),
                "warnings": list(self.warnings), "notes": list(self.notes)}

    def _delay_json(self) -> dict:
        """The delay the data show between the steer and the outputs beyond the model's
        (stid.fit.intervals.delay_allowance), and whether the intervals hold the answer with it."""
        seen = self.extra.get("delay_seen_ms")
        if seen is None:
            return {}
        return {"delay_seen_ms": {"value": round(float(seen[0]), 4), "stderr": round(float(seen[1]), 4),
                                  "intervals_allow_for_it": self.delay_allowance is not None}}

    def delay_words(self) -> str:
        """One line on a delay the intervals allow for ('' when none)."""
        seen = self.extra.get("delay_seen_ms")
        if seen is None or self.delay_allowance is None:
            return ""
        way = "later" if seen[0] > 0 else "earlier"
        if abs(seen[0]) < DELAY_WORTH_MS:  # (a trial user was sent to fit +sensor_delay for 0.12 ms of none)
            fix = (f"under {DELAY_WORTH_MS:g} ms, too little to add an effect for (a speed measured coarsely or "
                   "late, a sensor filter declared of another order, move it so)")
        elif "sensor_delay" in self.model.split("+"):
            fix = ("beyond its own sensor_delay: a sensor filter of another order or bandwidth than the vehicle "
                   "file's [sensors] declares shows so (accel_filter_order, gyro_filter_order)")
        else:
            fix = ("fit +sensor_delay to take it in" if seen[0] > 0 else
                   "the steer is timed late (a command timed by its receive time?), or a sensor filter is declared "
                   "slower or of a higher order than it is ([sensors])")
        return (f"the outputs answer the steer {abs(seen[0]):.2f} ms (std. error {seen[1]:.2f}) {way} than "
                f"{self.model} has them: its intervals allow for it; {fix}")

    def table(self) -> str:
        lines = [f"model {self.model}   method {self.method}   "
                 f"(cornering stiffness per axle, N/rad; ISO 8855 axes; SI units)", ""]
        head = f"  {'parameter':<14}{'value':>13}{'std. error':>13}{'95% interval':>30}  unit"
        lines.append(head)
        lines.append("  " + "-" * (len(head) + 6))
        widened = False
        for name, v, se, (lo, hi), half, ok in zip(self.names, self.values, self.stderr, self.ci95, self.half95,
                                                   self.determined):
            if not ok:
                lines.append(f"  {name:<14}{_num(v):>13}{'-':>13}           no interval ({self.undetermined[name]})  "
                             f"{self.units[name]}")
                continue
            pct = 100 * se / abs(v) if v else 0.0
            # (a std. error under 0.1% of the value kept two digits: '(0.0%)' read as none)
            rel = (f"({pct:.1f}%)" if pct >= 0.1 else f"({pct:.1g}%)") if v else ""
            # an interval the model-error allowance or a t of few blocks made wider than ~2 standard
            # errors says so on its row: the two columns would disagree without a word
            wide = half / se if se > 0 else 0.0
            mark = f"  (+-{wide:.1f} se)" if wide > WIDE_SE else ""
            widened |= bool(mark)
            lines.append(f"  {name:<14}{at_resolution(v, se):>13}{se_text(se):>13} {rel:>8}  "
                         f"[{at_resolution(lo, se)}, {at_resolution(hi, se)}]  {self.units[name]}{mark}")
        for name, (v, unit, why) in self.fixed.items():
            lines.append(f"  {name:<14}{_num(v):>13}{'fixed':>13}           {why}  {unit}")
        if self.fit:
            lines.append("")
            lines.append("  fit: " + "   ".join(f"{k} {v:.1f}%" if np.isfinite(v) else f"{k} n/a (it does not vary)"
                                               for k, v in self.fit.items())
                         + "   (100 (1 - |y - yhat| / |y - mean y|))")
        if self.k > 1:
            c = self.corr
            strong = [(self.names[i], self.names[j], c[i, j]) for i in range(self.k) for j in range(i + 1, self.k)
                      if abs(c[i, j]) > 0.8]
            if strong:
                lines.append("  strongly correlated: " + ", ".join(f"{a}-{b} {r:+.2f}" for a, b, r in strong))
        verdict = self.verdict_line()
        if verdict:
            lines.append(f"  {verdict}")
        if self.interval and self.converged:
            lines.append(f"  {self.interval}"
                         + ("; a row marked (+-N se) has an interval that reaches N standard errors either side "
                            "of its value (in log space for a positive parameter), for the reasons above"
                            if widened else ""))
        for w in self.notes:
            lines.append(f"  note: {w}")
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


    def verdict_line(self) -> str:
        """One line when the numbers are not all an answer: a fit that did not converge, or the
        parameters the data do not determine; empty otherwise."""
        if not self.converged:
            return (f"NOT CONVERGED: these values are where the solver stopped, not an optimum, and have no "
                    f"intervals ({self.status})")
        if self.undetermined:
            return ("no interval for " + ", ".join(f"{n} ({why})" for n, why in self.undetermined.items())
                    + ": the data do not determine " + ("it" if len(self.undetermined) == 1 else "them"))
        return ""


MAX_SPAN = 1e3  # hi/lo of a positive parameter's interval beyond which it is no interval
WIDE_SE = 2.5  # half-width / std. error beyond which a row says how wide (noise alone: t ~ 1.96-2.4)


def _num(x: float) -> str:
    if x == 0 or not np.isfinite(x):
        return f"{x:g}"
    return f"{x:.4g}"


def at_resolution(x: float, se: float) -> str:
    """``x`` to the decimal of its standard error's second significant digit (metrology's
    convention, GUM 7.2.6), trailing zeros kept: a bound of 399.963 with a std. error of 0.83
    prints 399.96. At four significant digits it printed 400, and read as holding a truth of
    400 that it misses. Without a usable standard error: four significant digits."""
    if x == 0 or not (np.isfinite(x) and np.isfinite(se) and se > 0):
        return _num(x)
    digits = int(np.floor(np.log10(abs(x)))) - int(np.floor(np.log10(se))) + 2
    s = f"{x:#.{min(max(digits, 2), 12)}g}"
    return s if "e" in s else s.rstrip(".")


def se_text(se: float) -> str:
    """A standard error to two significant digits (the resolution at_resolution prints to)."""
    if not (np.isfinite(se) and se > 0):
        return _num(se)
    s = f"{se:#.2g}"
    return s if "e" in s else s.rstrip(".")
