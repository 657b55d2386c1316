"""A long record is fitted on a sample of it first, then as a whole from there
(stid.fit.time_fit.coarse_sample): the same optimum, by the same stopping rule, for far fewer
simulations of the whole record.

The car is written here from plain physics, apart from stid's models: a linear single track at
a constant speed per stretch with a first-order servo lag, simulated exactly for a steer taken
linearly between samples (scipy's lsim). The bicycle misses the lag, so its solver closes in on
the optimum only linearly (its residuals are large): the case where a long record cost most."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from stid.fit import dataset
from stid.fit import time_fit
from stid.models.model import Model
from stid.run import Run
from stid.vehicle_file import Vehicle

M, A, B, IZ, CF, CR = 9.31, 0.2326, 0.2874, 0.65, 270.0, 275.0
LAG_S = 0.04  # the servo's time constant: what the bicycle misses
FS = 100.0


def _single_track_with_servo(vx: float) -> signal.StateSpace:
    """States (delta, vy, r), input the commanded steer, outputs (ay, r); ISO 8855, small angles:
    delta' = (u - delta) / tau; m (vy' + vx r) = Cf alpha_f + Cr alpha_r; Iz r' = a Cf alpha_f -
    b Cr alpha_r; alpha_f = delta - (vy + a r) / vx, alpha_r = -(vy - b r) / vx; ay = vy' + vx r."""
    ff = np.array([CF, -CF / vx, -CF * A / vx])  # Cf alpha_f as a row over (delta, vy, r)
    fr = np.array([0.0, -CR / vx, CR * B / vx])
    lateral = (ff + fr) / M
    Amat = np.vstack([[-1.0 / LAG_S, 0.0, 0.0], lateral - [0.0, 0.0, vx], (A * ff - B * fr) / IZ])
    Bmat = np.array([[1.0 / LAG_S], [0.0], [0.0]])
    C = np.vstack([lateral, [0.0, 0.0, 1.0]])
    return signal.StateSpace(Amat, Bmat, C, np.zeros((2, 1)))


def _run(name: str, vx: float, seconds: float, seed: int) -> Run:
    """``seconds`` of random steer (band-limited to 3 Hz, 3 degrees rms) at ``vx``, after 2 s at
    a stand-still, with the sensors' noise."""
    rng = np.random.default_rng(seed)
    n_still, n = int(2 * FS), int(seconds * FS)
    steer = signal.sosfiltfilt(signal.butter(4, 3.0, fs=FS, output="sos"), rng.standard_normal(n))
    steer *= np.radians(3.0) / np.std(steer)
    t = np.arange(n) / FS
    _, y, _ = signal.lsim(_single_track_with_servo(vx), steer, t)
    pad = np.zeros(n_still)
    ay = np.r_[pad, y[:, 0]] + 0.05 * rng.standard_normal(n_still + n)
    r = np.r_[pad, y[:, 1]] + 0.004 * rng.standard_normal(n_still + n)
    speed = np.r_[pad, np.full(n, vx)]
    return Run(name, np.arange(n_still + n) / FS, np.r_[pad, steer], ay, r, speed, None, None, {}, {})


@pytest.fixture(scope="module")
def long_record():
    """Six minutes of driving: four stretches at 3-6 m/s, each from its own steer."""
    runs = [_run(f"run{k}", vx, 90.0, seed=k) for k, vx in enumerate((3.0, 4.0, 5.0, 6.0))]
    return dataset.dynamic_stretches(runs)


def _fitted(monkeypatch, model_name, stretches, coarse_from: float):
    """The model's fit, and how many samples of the whole record it simulated."""
    whole = {id(st) for st in stretches}
    count = {"samples": 0}

    def counted_many(model, ps, st, _real=time_fit.simulate_many):
        if id(st) in whole:
            count["samples"] += len(ps) * len(st.t)
        return _real(model, ps, st)

    def counted(model, p, st, _real=time_fit.simulate):
        if id(st) in whole:
            count["samples"] += len(st.t)
        return _real(model, p, st)

    vehicle = Vehicle("plain physics", M, A, B, sensors={"accel_bandwidth_hz": 0.0, "gyro_bandwidth_hz": 0.0})
    with monkeypatch.context() as m:
        m.setattr(time_fit, "COARSE_FROM", coarse_from)
        m.setattr(time_fit, "simulate_many", counted_many)
        m.setattr(time_fit, "simulate", counted)
        res = time_fit.fit_time(Model(model_name, vehicle), stretches, intervals="noise")
    return res, count["samples"]


# the model, and the share of the whole record's simulations the sample leaves at most (measured:
# 0.73 for the bicycle, which misses the lag and creeps through its weights' rounds again on the
# whole from a sample's answer that model error, not noise, keeps apart from the whole's; 0.3 for
# the right model, whose three starts are taken on the sample)
@pytest.mark.parametrize("model_name, share", [("bicycle", 0.9), ("bicycle+actuator_lag", 0.5)])
def test_a_long_record_fitted_from_a_sample_reaches_the_same_optimum_for_fewer_simulations(monkeypatch, long_record,
                                                                                           model_name, share):
    assert sum(len(st.t) * st.dt for st in long_record) >= time_fit.COARSE_FROM * time_fit.COARSE_S
    whole, n_whole = _fitted(monkeypatch, model_name, long_record, coarse_from=np.inf)  # the whole from the start
    sampled, n_sampled = _fitted(monkeypatch, model_name, long_record, coarse_from=time_fit.COARSE_FROM)
    assert whole.converged and sampled.converged
    # the same optimum: the two ends differ by what the stopping rule leaves (a tenth of a standard
    # error of the step still to go, each), far inside what a fit that had not converged may be off
    apart = np.abs(sampled.values - whole.values) / whole.stderr
    assert np.all(apart < 0.5), (apart, whole.params(), sampled.params())
    assert n_sampled < share * n_whole, (n_sampled, n_whole)
    # the solver's words say where the evaluations went (they count the whole record's only)
    assert "started where the fit of a sample" in sampled.status and "sample" not in whole.status, sampled.status
    if model_name != "bicycle":  # the right model finds the car (to 0.1-0.4% here, both ways)
        truth = {"Cf": CF, "Cr": CR, "Iz": IZ, "tau_steer": LAG_S}
        for name, value in sampled.params().items():
            assert abs(value / truth[name] - 1) < 0.01, (name, value, truth[name])


def test_a_record_a_fit_is_made_for_is_fitted_whole_and_a_long_one_sampled_across_it(long_record):
    short = long_record[:2]  # three minutes
    assert time_fit.coarse_sample(short) is None
    sample = time_fit.coarse_sample(long_record)
    seconds = sum(len(st.t) * st.dt for st in sample)
    assert abs(seconds - time_fit.COARSE_S) < 0.25 * time_fit.COARSE_S, seconds
    # spread: a piece of each of the four stretches (their speeds), drawn the same way every time
    assert sorted({st.vx for st in sample}) == sorted({st.vx for st in long_record})
    again = time_fit.coarse_sample(long_record)
    assert [(st.name, st.t[0]) for st in again] == [(st.name, st.t[0]) for st in sample]
