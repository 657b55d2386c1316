"""A small linear state-space type with named states, inputs and outputs, and
the operations effects need: put a block in front of an input, add states
driven by outputs, change an output row. Simulation discretises once (zero-
order hold) and filters with scipy (no Python loop per sample); frequency
responses are evaluated for all frequencies in one solve."""

from __future__ import annotations

from dataclasses import dataclass, field

from stid.lazy_numpy import np


def foh(A, B, C, D, dt):
    """First-order-hold discretisation, identical to scipy.signal.cont2discrete 'foh'.

    For a diagonalisable A the hold integrals have closed forms in the eigenbasis
    (one small eigendecomposition instead of a matrix exponential, which costs
    milliseconds for the stiff systems a fit explores); otherwise expm.
    """
    n, m = B.shape
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) < 1e8 and np.all(np.abs(lam) * dt > 1e-6):
        z = lam * dt
        ez = np.exp(z)
        Vi = np.linalg.inv(V)
        Bt = Vi @ B
        F = (V * ez) @ Vi
        G1 = V @ (((ez - 1) / lam)[:, None] * Bt)  # int_0^h e^{As} ds B
        G2 = V @ (((ez - 1 - z) / (lam * z))[:, None] * Bt)  # int_0^h e^{As} (1 - s/h) ds B
        F, G1, G2 = F.real, G1.real, G2.real
    else:
        M = np.zeros((n + 2 * m, n + 2 * m))
        M[:n, :n] = A * dt
        M[:n, n:n + m] = B * dt
        M[n:n + m, n + m:] = np.eye(m)
        from scipy import linalg  # here: `stid --help` lists the effects without importing scipy

        E = linalg.expm(M)
        F, G1, G2 = E[:n, :n], E[:n, n:n + m], E[:n, n + m:]
    return F, G1 - G2 + F @ G2, C, D + C @ G2


def foh_input(u: np.ndarray) -> np.ndarray:
    """Samples whose first-order hold carries the band-limited signal they were taken from.

    The hold draws chords between the samples; a chord lies off the curve by
    -(h^2 / 8) u'' at its middle, so over a step it scales a component at w by
    sinc^2 ~ 1 - (w h)^2 / 12: a zero-phase loss that grows with frequency, the very
    shape of an inertia and of a servo lag. At the fit rate (h = 4 ms) it cost Iz
    -0.21% on exact single-track data (tests/test_servo_lag.py). Taking a twelfth of
    the second difference off each sample restores the gain to O(h^4) (-0.005%).
    The end samples are kept (no neighbour on one side).

    Exact for dynamics slower than the sample rate, which is what the chords' integral
    feeds. A state far faster than it (a lag of tau -> 0) follows the input pointwise and
    sees the corrected sample instead of the true one, off by a twelfth of the second
    difference (~5e-4 of 3 Hz steer at 250 Hz): the zero limit of such an effect then
    differs from the model without it by that much (tests/test_effects_contract.py).
    A cubic hold in the discretisation would be exact for both; not done yet."""
    u = np.asarray(u, float)
    if u.ndim != 1 or len(u) < 3:
        return u
    out = u.copy()
    out[1:-1] -= (u[2:] - 2.0 * u[1:-1] + u[:-2]) / 12.0
    return out


def _steady_zi(num, den):
    """lfilter state for a unit constant input already in steady state (transposed
    direct form II), or None for a filter without a steady state (a pole at z = 1)."""
    s = den.sum()
    if abs(s) < 1e-12:
        return None
    y = num.sum() / s
    d = num - den * y  # den[0] == 1
    return np.cumsum(d[::-1])[::-1][1:]


def _matrix(x) -> np.ndarray:
    """A float 2-D array of x (a nested list or an array)."""
    a = np.asarray(x, dtype=float)
    return a if a.ndim == 2 else np.atleast_2d(a)


@dataclass
class LinSys:
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: list
    inputs: list
    outputs: list
    offsets: dict = field(default_factory=dict)  # constant added to an output after simulation

    def out(self, name: str) -> int:
        return self.outputs.index(name)

    def inp(self, name: str) -> int:
        return self.inputs.index(name)

    def copy(self) -> "LinSys":
        return LinSys(self.A.copy(), self.B.copy(), self.C.copy(), self.D.copy(), list(self.states),
                      list(self.inputs), list(self.outputs), dict(self.offsets))

    # -- composition --------------------------------------------------------
    def series_input(self, name: str, A, B, C, D, states, new_input: str) -> "LinSys":
        """Feed input ``name`` from a SISO block (A, B, C, D) whose input is ``new_input``."""
        k = self.inp(name)
        n, m = len(self.states), len(states)
        A, B, C, D = (_matrix(x) for x in (A, B, C, D))
        bk = self.B[:, k:k + 1]
        dk = self.D[:, k:k + 1]
        # preallocated blocks, not np.block/vstack: every simulation builds the model a few
        # times, and this is most of a build
        A2 = np.zeros((n + m, n + m))
        A2[:n, :n] = self.A
        A2[:n, n:] = bk * C  # (n, 1) x (1, m): an outer product
        A2[n:, n:] = A
        B2 = np.zeros((n + m, len(self.inputs)))
        B2[:n] = self.B
        B2[:n, k] = bk[:, 0] * D[0, 0]
        B2[n:, k] = B[:, 0]
        C2 = np.zeros((len(self.outputs), n + m))
        C2[:, :n] = self.C
        C2[:, n:] = dk * C
        D2 = self.D.copy()
        D2[:, k] = dk[:, 0] * D[0, 0]
        inputs = list(self.inputs)
        inputs[k] = new_input
        return LinSys(A2, B2, C2, D2, self.states + list(states), inputs, list(self.outputs), dict(self.offsets))

    def add_states(self, names, A_new, drive: dict) -> "LinSys":
        """Append states x_new with x_new' = A_new x_new + sum_o drive[o] * y_o,
        where y_o are outputs of this system (column vectors)."""
        n, m = len(self.states), len(names)
        A2 = np.zeros((n + m, n + m))
        A2[:n, :n] = self.A
        A2[n:, n:] = _matrix(A_new)
        B2 = np.zeros((n + m, len(self.inputs)))
        B2[:n] = self.B
        for o, col in drive.items():
            col = np.asarray(col, float).reshape(m, 1)
            i = self.out(o)
            A2[n:, :n] += col * self.C[i]
            B2[n:, :] += col * self.D[i]
        C2 = np.zeros((len(self.outputs), n + m))
        C2[:, :n] = self.C
        return LinSys(A2, B2, C2, self.D.copy(), self.states + list(names), list(self.inputs),
                      list(self.outputs), dict(self.offsets))

    def add_to_output(self, target: str, source: str | None = None, gain: float = 1.0,
                      state: str | None = None) -> None:
        """y_target += gain * y_source (an output) or gain * x_state (a state), in place."""
        t = self.out(target)
        if source is not None:
            s = self.out(source)
            self.C[t, :] += gain * self.C[s, :]
            self.D[t, :] += gain * self.D[s, :]
        if state is not None:
            self.C[t, self.states.index(state)] += gain

    def filter_output(self, name: str, f_hz: float, order: int = 1) -> "LinSys":
        """Pass output ``name`` through a first-order low-pass at f_hz (a sensor's bandwidth):
        a state x' = w (y - x) that replaces the output; ``order`` 2: a second-order Butterworth,
        x'' = w^2 (y - x) - sqrt(2) w x'. (add_states, written out, with scalars: every simulation
        builds the model with its two sensor filters a few times.)"""
        w = 2 * np.pi * f_hz
        i = self.out(name)
        n = len(self.states)
        k = 2 if order == 2 else 1
        A2 = np.zeros((n + k, n + k))
        A2[:n, :n] = self.A
        B2 = np.zeros((n + k, len(self.inputs)))
        B2[:n] = self.B
        last, gain = n + k - 1, (w * w if k == 2 else w)  # the state the output's input drives
        A2[last, :n] = gain * self.C[i]
        B2[last] = gain * self.D[i]
        if k == 2:  # the filtered output and its rate
            A2[n, n + 1] = 1.0
            A2[last, n] = -w * w
            A2[last, last] = -np.sqrt(2.0) * w
        else:
            A2[n, n] = -w
        C2 = np.zeros((len(self.outputs), n + k))
        C2[:, :n] = self.C
        C2[i, :] = 0.0
        C2[i, n] = 1.0
        D2 = self.D.copy()
        D2[i, :] = 0.0
        return LinSys(A2, B2, C2, D2, self.states + [f"filt_{name}", f"filt_{name}_rate"][:k], list(self.inputs),
                      list(self.outputs), dict(self.offsets))

    def select(self, outputs) -> "LinSys":
        idx = [self.out(o) for o in outputs]
        return LinSys(self.A, self.B, self.C[idx], self.D[idx], self.states, self.inputs, list(outputs),
                      {k: v for k, v in self.offsets.items() if k in outputs})

    # -- analysis ---------------------------------------------------------
    def freqresp(self, f_hz: np.ndarray, inp: str = "delta") -> np.ndarray:
        """Complex response of every output to ``inp`` at the frequencies [Hz]: (n_out, n_f)."""
        k = self.inp(inp)
        s = 2j * np.pi * np.asarray(f_hz)
        n = len(self.states)
        M = s[:, None, None] * np.eye(n)[None] - self.A[None]
        X = np.linalg.solve(M, np.broadcast_to(self.B[:, k], (len(s), n))[..., None])[..., 0]
        return (X @ self.C.T).T + self.D[:, [k]]

    def to_control(self):
        import control

        return control.ss(self.A, self.B, self.C, self.D, inputs=self.inputs, outputs=self.outputs,
                          states=self.states)

    def simulator(self, dt: float, outputs=None, inputs=None):
        """Precompute the discrete transfer functions once; return ``sim(u) -> y``.

        Discretised with a first-order hold: the sampled input is taken as piecewise
        linear. A zero-order hold would treat it as a staircase, which lags a smooth
        input by half a sample and biases every lag-like parameter (inertia, servo
        lag, relaxation). Each output is a sum of SISO discrete transfer functions
        filtered with scipy.signal.lfilter (C speed): numerically sound for the few
        states of these models and far faster than a Python loop over samples. The
        response starts in the steady state of the first input sample.
        """
        from scipy import signal  # here, not at the top: slow to import, and the fits run LPV

        outs = list(self.outputs if outputs is None else outputs)
        idx = [self.out(o) for o in outs]
        ins = [self.inp(i) for i in (self.inputs if inputs is None else inputs)]
        Ad, Bd, Cd, Dd = foh(self.A, self.B[:, ins], self.C[idx], self.D[np.ix_(idx, ins)], dt)
        den = np.poly(Ad).real
        n = len(den) - 1
        # Markov parameters h_0 = D, h_k = C Ad^(k-1) Bd give the numerator of every
        # input-output pair at once: num = den * H(z), truncated to degree n.
        h = np.zeros((n + 1, len(idx), len(ins)))
        h[0] = Dd
        X = Bd
        for k in range(1, n + 1):
            h[k] = Cd @ X
            X = Ad @ X
        nums = np.zeros((n + 1, len(idx), len(ins)))
        for k in range(n + 1):
            nums[k] = np.tensordot(den[: k + 1][::-1], h[: k + 1], axes=(0, 0))
        tfs = [[nums[:, j, k] for k in range(len(ins))] for j in range(len(idx))]
        zi_unit = [[_steady_zi(num, den) for num in row] for row in tfs]
        offsets = [self.offsets.get(o, 0.0) for o in outs]

        D_cont = self.D[np.ix_(idx, ins)]

        def sim(u: np.ndarray, u_out: np.ndarray | None = None) -> np.ndarray:
            """Outputs for inputs u; ``u_out``: other samples of the inputs for the direct
            feedthrough D u alone (the held input drives the states, linsys.foh_input)."""
            u = np.asarray(u, float)
            if u.ndim == 1:
                u = u[:, None]
            y = np.zeros((len(u), len(outs)))
            for j, row in enumerate(tfs):
                for k, num in enumerate(row):
                    if k >= u.shape[1] or not np.any(num) or not np.any(u[:, k]):
                        continue
                    zi = zi_unit[j][k]
                    if zi is not None:
                        y[:, j] += signal.lfilter(num, den, u[:, k], zi=zi * u[0, k])[0]
                    else:
                        y[:, j] += signal.lfilter(num, den, u[:, k])
                y[:, j] += offsets[j]
            if u_out is not None:
                du = np.asarray(u_out, float)
                y += ((du[:, None] if du.ndim == 1 else du) - u) @ D_cont.T
            return y

        return sim

    def simulate(self, u: np.ndarray, dt: float, outputs=None, inputs=None) -> np.ndarray:
        """Response to inputs u (n_t, n_in) sampled at dt: (n_t, n_out)."""
        return self.simulator(dt, outputs, inputs)(u)
