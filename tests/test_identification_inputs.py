"""Bad input ends in one clear message and a non-zero exit; the loaders' contracts."""

import subprocess

import numpy as np
import pytest

from conftest import REPO, tool
from simdata import random_steer_pair

VEHICLE = REPO / "docs" / "examples" / "rc8.toml"


def stid(*args):
    return subprocess.run([tool("stid"), *map(str, args)], capture_output=True, text=True, timeout=120)


def write_csv(path, cols):
    names = list(cols)
    rows = np.column_stack([cols[n] for n in names])
    path.write_text(",".join(names) + "\n" + "\n".join(",".join(f"{v:.6g}" for v in r) for r in rows) + "\n")
    return path


def good_cols(n=3000, fs=100.0):
    t = np.arange(n) / fs
    rng = np.random.default_rng(0)
    steer = 0.03 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * rng.standard_normal(n)
    return {"t": t, "steer": steer, "ay": 20 * steer, "r": 3 * steer, "vx": np.full(n, 5.0)}


def assert_fails(r, *words):
    assert r.returncode != 0, r.stdout
    assert "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) <= 3, r.stderr
    for w in words:
        assert w in r.stderr, r.stderr


def test_missing_columns(tmp_path):
    cols = good_cols()
    del cols["r"]
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE), "lacks the column", "r")


def test_nan_values(tmp_path):
    """A few: gaps, left out and said (tests/test_bad_input.py); most of a column: the wrong column."""
    cols = good_cols()
    cols["ay"][100:105] = np.nan
    r = stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE)
    assert r.returncode == 0 and "5 row(s) (0.2%) lack a value" in r.stderr, r.stderr
    cols["ay"][:2000] = np.nan
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE), "'ay'", "missing",
                 "the right column")


def test_degrees_instead_of_radians(tmp_path):
    cols = good_cols()
    cols["steer"] = np.degrees(cols["steer"]) * 5
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE), "degrees", "steer")


def test_constant_steer(tmp_path):
    cols = good_cols()
    cols["steer"][:] = 0.02
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE, "--method", "time"),
                 "constant")


def test_run_too_short(tmp_path):
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", {k: v[:10] for k, v in good_cols().items()}),
                      "--vehicle", VEHICLE), "only 10 rows")


def test_run_without_a_constant_speed_stretch(tmp_path):
    cols = good_cols()
    cols["vx"] = np.linspace(2.0, 12.0, len(cols["t"]))  # accelerating all the way
    # the frequency-response method needs one speed and says so; the time-domain fit follows
    # the measured speed (tests/test_track_runs.py fits such runs)
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE, "--method", "freq"),
                 "constant speed")


def test_unreadable_and_empty_files(tmp_path):
    (tmp_path / "e.mcap").write_bytes(b"")
    assert_fails(stid("fit", tmp_path / "e.mcap", "--vehicle", VEHICLE), "empty")
    (tmp_path / "g.csv").write_bytes(b"\x00\xff\xfe garbage \x01")
    assert_fails(stid("fit", tmp_path / "g.csv", "--vehicle", VEHICLE))
    assert_fails(stid("fit", tmp_path / "nope.csv", "--vehicle", VEHICLE), "does not exist")


def test_vehicle_file_without_mass(tmp_path):
    v = tmp_path / "v.toml"
    v.write_text('name = "x"\na = 0.2\nb = 0.3\n')
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", good_cols()), "--vehicle", v), "mass")
    v.write_text('mass = 9310\na = 232.6\nb = 287.4\n')
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", good_cols()), "--vehicle", v), "kg and m")
    v.write_text('mass = 3.2\na = 150\nb = 0.2\n')  # only a is wrong (mm): only a is named
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", good_cols()), "--vehicle", v), ": a 150 m looks implausible")
    v.write_text("mass = [oops\n")
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", good_cols()), "--vehicle", v), "TOML")


def test_unknown_model_and_effect(tmp_path):
    csv = write_csv(tmp_path / "a.csv", good_cols())
    assert_fails(stid("fit", csv, "--vehicle", VEHICLE, "--model", "bicycle+warp_drive"), "unknown effect",
                 "actuator_lag")
    assert_fails(stid("fit", csv, "--vehicle", VEHICLE, "--model", "tricycle"), "unknown base model")


def test_irregular_time_is_resampled_with_a_warning(tmp_path):
    from stid.load import load_csv

    cols = good_cols()
    cols["t"] = cols["t"] + np.random.default_rng(1).uniform(0, 0.004, len(cols["t"]))
    cols["t"].sort()
    run = load_csv(write_csv(tmp_path / "a.csv", cols))
    assert np.allclose(np.diff(run.t), np.diff(run.t)[0])
    assert any("irregular" in w for w in run.meta["warnings"])


def test_json_mode_keeps_stdout_clean(simdir):
    import json

    r = stid("fit", *random_steer_pair(simdir), "--vehicle", VEHICLE, "--method", "freq", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["params"]["Cf"]["unit"] == "N/rad"


def test_truncated_mcap_is_read_up_to_the_cut(simdir, tmp_path):
    from stid.load import load_file

    src = random_steer_pair(simdir)[0]
    data = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    full = load_file(src)[0]
    part = load_file(cut)[0]
    assert 0.3 * len(full) < len(part) < len(full)
    assert np.allclose(part.ay, full.ay[: len(part)])
    assert any("cut short" in w for w in part.meta["warnings"])


def test_model_frequency_response_agrees_with_python_control(rc_vehicle):
    import control

    from stid.models.model import Model

    m = Model("bicycle+actuator_lag+tyre_relaxation+body_roll+accel_offset", rc_vehicle)
    p = m.defaults()
    f = np.logspace(-1, 1.3, 40)
    ours = m.freqresp(p, f, 5.0)
    sys = m.build(p, 5.0).select(["ay", "r"])
    resp = control.frequency_response(sys.to_control(), 2 * np.pi * f)
    theirs = np.asarray(resp.complex)[:, 0, :] if np.asarray(resp.complex).ndim == 3 else np.asarray(resp.complex)
    assert np.allclose(ours, theirs, rtol=1e-8, atol=1e-10)


def test_steady_state_gain_matches_the_understeer_formula(rc_vehicle):
    from stid.models.model import Model

    m = Model("bicycle", rc_vehicle)
    p = {"Cf": 400.0, "Cr": 475.0, "Iz": 0.25}
    v = rc_vehicle
    K = v.mass / v.L * (v.b / p["Cf"] - v.a / p["Cr"])
    for vx in (2.0, 5.0, 9.0):
        H = m.freqresp(p, np.array([1e-4]), vx)
        assert abs(H[1, 0]) == pytest.approx(vx / (v.L + K * vx ** 2), rel=1e-6)
        assert abs(H[0, 0]) == pytest.approx(vx ** 2 / (v.L + K * vx ** 2), rel=1e-6)


def test_the_fit_percent_of_an_output_that_does_not_vary_is_not_a_number():
    """On a circle at constant steer the steady fit's steer is constant up to round-off: the fit
    percent divided by that round-off and printed -7381009310664.4%."""
    from stid.fit.result import FitResult, fit_percent

    steer = np.full(50, 0.05) + 1e-18 * np.arange(50)  # constant but for round-off
    assert np.isnan(fit_percent(steer, steer + 1e-4))
    assert fit_percent(np.sin(np.arange(50.0)), np.sin(np.arange(50.0))) == 100.0
    res = FitResult(model="bicycle", method="steady", names=["eta"], values=np.array([0.004]),
                    cov=np.array([[1e-10]]), units={"eta": "rad/(m/s^2)"}, fit={"steer": fit_percent(steer, steer)})
    assert "steer n/a (it does not vary)" in res.table() and res.to_json()["fit"] == {"steer": None}


def test_an_interval_of_a_parameter_positive_by_nature_stays_positive():
    """A steady circle gave Cr [-1693, 6595] N/rad and Iz [-0.141, 0.633] kg m^2: values no car
    has. A parameter the solver fits in log space gets the same relative half-width there; where
    the half-width is small against the value, the interval is the symmetric one."""
    from stid.fit.result import FitResult

    res = FitResult(model="bicycle", method="time", names=["Cr", "Iz", "x_acc"], values=np.array([2451.0, 0.25, 0.08]),
                    cov=np.diag([2100.0, 1e-6, 0.1]) ** 2, units={}, n=10_000, positive=("Cr", "Iz"))
    (cr_lo, cr_hi), (iz_lo, iz_hi), (x_lo, x_hi) = res.ci95
    assert 0 < cr_lo < 2451.0 < cr_hi and np.sqrt(cr_lo * cr_hi) == pytest.approx(2451.0)
    half = 1.96 * 1e-6
    assert (iz_lo, iz_hi) == pytest.approx((0.25 - half, 0.25 + half), rel=1e-9)  # small: the same
    assert x_lo < 0 < x_hi  # an offset may be negative: symmetric


def test_a_run_cut_into_pieces_by_the_link_is_one_set_of_notes(capsys):
    """A lossy link cut a run into 12 pieces, and the loader's notes came out 21 lines: each piece's
    loss and gyro zero. A file's messages are said once, and its losses summed."""
    from stid.cli import _print_load_warnings
    from stid.load import _link_losses
    from stid.run import Run

    def piece(k, n, lost, file="drop.mcap"):
        name = file + (f"#{k}" if k > 1 else "")
        r = Run(name, np.arange(n) / 200.0, *(np.zeros(n) for _ in range(4)))
        r.meta.update(source=f"logs/{file}", link_lost=lost,  # (as the loader's _convert leaves them)
                      notes=["gyro zero taken from the stand-still of drop.mcap (same boot)"] if k > 1 else [],
                      warnings=["the file was cut short"])
        return r

    # piece #2 was too short to keep: the names are the pieces', not their places in the list
    drop, other = [piece(k, 1000, 400) for k in (1, 3, 4, 5)], [piece(1, 500, 0, "other.mcap")]
    _link_losses(drop)  # (the loader, per log)
    _link_losses(other)
    _print_load_warnings(drop + other)
    err = capsys.readouterr().err.splitlines()
    assert err.count("warning: drop.mcap (all 4 pieces): the file was cut short") == 1
    assert "note: drop.mcap#3, #4, #5: gyro zero taken from the stand-still of drop.mcap (same boot)" in err
    assert ("note: drop.mcap: 1600 samples lost on the link (40.0%), left out of every fit; the log is in 4 pieces, "
            "cut where samples were lost or the car restarted (drop.mcap, #3, #4, #5)") in err, err
    assert len(err) == 3 + 1, err  # and the other file's warning (it lost nothing)


def test_a_misspelt_model_is_heard_of_before_the_runs_are_read(tmp_path):
    """A trial user's misspelt --model came after a bag's notes, once the whole run was read."""
    cols = good_cols()
    cols["ay"][100:105] = np.nan  # (a note when the run is read)
    path = write_csv(tmp_path / "a.csv", cols)
    for args in (("fit", path, "--model", "bicylce"), ("diagnose", path, "--model", "bicycle+lagg"),
                 ("compare", path, "--model", "bicycle", "--model", "bicycle+lagg")):
        r = stid(*args, "--vehicle", VEHICLE)
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().splitlines() == [r.stderr.strip().splitlines()[-1]], r.stderr  # (no note first)
        assert "did you mean 'bicycle'" in r.stderr or "unknown effect 'lagg'" in r.stderr, r.stderr


@pytest.mark.parametrize("case, words", [("duplicate", "repeats at data row 1001 (line 1002"),
                                         ("clock reset", "goes back 0.5 s at data row 1001"),
                                         ("swapped rows", "out of order? sort them")])
def test_time_that_does_not_increase_is_named_by_what_it_looks_like(tmp_path, case, words):
    """Every time step back was told to 'sort the rows or remove duplicates': wrong advice for a
    clock reset or two logs joined (sorting interleaves two runs), and the row was the data row
    without saying so."""
    cols = good_cols()
    t = cols["t"]
    if case == "duplicate":
        t[1000] = t[999]
    elif case == "clock reset":
        t[1000:] -= 0.51  # (10 ms steps: 0.5 s back at the join)
    else:
        t[999], t[1000] = t[1000], t[999]
    assert_fails(stid("fit", write_csv(tmp_path / "a.csv", cols), "--vehicle", VEHICLE), words)
