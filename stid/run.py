"""A run: uniformly sampled signals in SI units, ISO 8855 axes, ready to fit."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


# the CSV contract's columns (DESIGN.md): SI units, ISO 8855 axes
REQUIRED = ("t", "steer", "ay", "r", "vx")
OPTIONAL = ("ax", "beta", "delta_cmd", "w_fl", "w_fr", "w_rl", "w_rr")

@dataclass
class Run:
    """One stretch of driving.

    Attributes
    ----------
    name : str
        Where it came from (file, and piece if the file was split).
    t : ndarray
        Time [s], uniform.
    steer : ndarray
        Front road-wheel angle [rad], positive left.
    ay, r, vx : ndarray
        Lateral acceleration [m/s^2], yaw rate [rad/s], forward speed [m/s].
    ax, beta : ndarray or None
        Longitudinal acceleration [m/s^2] and body slip angle [rad] when measured.
    extra : dict
        Any other columns (kept, ignored by the models).
    meta : dict
        Source, calibration used, warnings raised while loading.
    valid : ndarray of bool or None
        False at samples that were not measured (lost on the link) and only hold
        the grid's place; None when every sample is a measurement.
    steer_fine : ndarray or None
        The steer on a grid ``fine`` times as fine (``(len(t) - 1) * fine + 1`` samples, the
        first at ``t[0]``): a held command whose steps fall inside the sensors' sample periods
        (a ROS car's 50 Hz command against a 30-60 Hz IMU), for the models to be driven by
        (stid.fit.dataset.Stretch.simulation_input); None when ``steer`` serves.
    fine : int
        How many steer samples of ``steer_fine`` per sample period (1 without one).
    """

    name: str
    t: np.ndarray
    steer: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    vx: np.ndarray
    ax: np.ndarray | None = None
    beta: np.ndarray | None = None
    extra: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    valid: np.ndarray | None = None
    steer_fine: np.ndarray | None = None
    fine: int = 1
    _fs_of: tuple | None = field(default=None, init=False, repr=False, compare=False)  # (t, its fs)

    @property
    def fs(self) -> float:
        # a median over every sample, asked for dozens of times per command (each live update
        # too): kept while t is the same array (held, so its id cannot be reused)
        if self._fs_of is None or self._fs_of[0] is not self.t:
            self._fs_of = (self.t, 1.0 / float(np.median(np.diff(self.t))))
        return self._fs_of[1]

    @property
    def dt(self) -> float:
        return 1.0 / self.fs

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    def __len__(self) -> int:
        return len(self.t)

    def slice(self, i0: int, i1: int, name: str | None = None) -> "Run":
        cut = lambda x: None if x is None else x[i0:i1]  # noqa: E731
        return Run(name or self.name, self.t[i0:i1], self.steer[i0:i1], self.ay[i0:i1], self.r[i0:i1],
                   self.vx[i0:i1], cut(self.ax), cut(self.beta), {k: v[i0:i1] for k, v in self.extra.items()},
                   dict(self.meta), None if self.valid is None else self.valid[i0:i1],
                   steer_fine=fine_piece(self.steer_fine, self.fine, i0, i1, len(self.t)), fine=self.fine)

    def warn(self, text: str) -> None:
        self.meta.setdefault("warnings", []).append(text)


def fine_piece(fine_x, fine: int, i0: int, i1: int, n: int):
    """The part of a series ``fine`` times as fine as a grid of ``n`` samples (``(n - 1) * fine + 1``
    of them) that spans the grid's samples ``i0 .. i1 - 1`` (Python slice bounds; None stays None)."""
    if fine_x is None:
        return None
    i0, i1, _ = slice(i0, i1).indices(n)
    return fine_x[i0 * fine:max(i1 - 1, i0) * fine + 1]
