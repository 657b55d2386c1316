"""A newcomer's mistakes end in one clear line and a non-zero exit, before any work, and no
file a user made is replaced unasked (every command that writes has --overwrite)."""

import subprocess

import pytest

from conftest import REPO, tool

VEHICLE = str(REPO / "docs" / "examples" / "rc8.toml")


def _run(*words, timeout=60):
    return subprocess.run([tool(words[0]), *map(str, words[1:])], capture_output=True, text=True, timeout=timeout)


def _check_one_clear_line(r, *says):
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    for s in says:
        assert s in last, (s, r.stderr)


def test_export_does_not_replace_a_csv_unasked_and_says_so_before_loading(tmp_path):
    mine = tmp_path / "mine.csv"
    mine.write_text("t,steer\n")
    # the run does not even exist: the refusal comes first, before any loading
    r = _run("stid", "export", tmp_path / "nowhere.mcap", "--csv", mine)
    _check_one_clear_line(r, "mine.csv exists", "--overwrite")
    assert mine.read_text() == "t,steer\n"


def test_report_refuses_a_directory_that_holds_a_report_before_any_work(tmp_path):
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "report.html").write_text("<p>mine</p>")
    r = _run("stid", "report", tmp_path / "nowhere.mcap", "--vehicle", VEHICLE, "-o", rep)
    _check_one_clear_line(r, "report.html exists", "--overwrite")
    assert (rep / "report.html").read_text() == "<p>mine</p>"
    # a file as -o is said before the runs are read, too
    (tmp_path / "a_file").write_text("")
    r = _run("stid", "report", tmp_path / "nowhere.mcap", "--vehicle", VEHICLE, "-o", tmp_path / "a_file")
    _check_one_clear_line(r, "is a file")
    # and a directory that cannot be made, without making anything
    r = _run("stid", "report", tmp_path / "nowhere.mcap", "--vehicle", VEHICLE, "-o", tmp_path / "a_file" / "rep")
    _check_one_clear_line(r, "cannot make the report directory")


def test_calibrate_and_batch_and_repair_do_not_replace_files_unasked(tmp_path):
    out = tmp_path / "car.toml"
    out.write_text("# mine\n")
    r = _run("stid", "calibrate", tmp_path / "nowhere.mcap", "--vehicle", VEHICLE, "-o", out)
    _check_one_clear_line(r, "car.toml exists", "--overwrite")
    assert out.read_text() == "# mine\n"
    table = tmp_path / "t.csv"
    table.write_text("mine\n")
    r = _run("stid", "batch", tmp_path, "--vehicle", VEHICLE, "-o", table)
    _check_one_clear_line(r, "t.csv exists", "--overwrite")
    assert table.read_text() == "mine\n"
    notes = tmp_path / "notes.mcap"
    notes.write_text("not a log, but mine")
    r = _run("stid", "repair", tmp_path / "nowhere.mcap", "-o", notes)
    _check_one_clear_line(r, "exists", "repair does not replace")
    assert notes.read_text() == "not a log, but mine"


@pytest.mark.parametrize("option", [["--duration", "inf"], ["--duration", "1e12"], ["--duration", "nan"],
                                    ["--still", "inf"], ["--stall", "1:inf"], ["--reconnect-after", "inf"]])
def test_stid_sim_refuses_endless_times_in_one_line(tmp_path, option):
    r = _run("stid-sim", "--fast", "-o", tmp_path / "x.mcap", *option)
    _check_one_clear_line(r, option[0])
    assert not (tmp_path / "x.mcap").exists()


def test_stid_log_refuses_a_time_that_is_not_positive():
    r = _run("stid-log", "/dev/null", "--duration", "nan")
    _check_one_clear_line(r, "--duration", "positive")


def test_an_effect_typo_gets_a_did_you_mean(tmp_path):
    from stid.errors import InputError
    from stid.models.model import Model
    from stid.vehicle_file import load_vehicle

    with pytest.raises(InputError, match="did you mean 'actuator_lag'"):
        Model("bicycle+actuator_lagg", load_vehicle(VEHICLE))
    r = _run("stid-sim", "--fast", "-o", tmp_path / "x.mcap", "--effects", "actuator_lagg")
    _check_one_clear_line(r, "did you mean actuator_lag")


def test_the_loggers_summary_says_why_it_stopped_in_words():
    from host.logger import summary_line

    stats = {"errors": {"crc": 0}, "file": "run.mcap", "samples": 10, "frames": {"samples": 1}, "lost_frames": 0,
             "missing_samples": 0, "mcu_overruns": 0, "gaps": []}
    said = {reason: summary_line(dict(stats, stop=reason)) for reason in ("port gone", "duration", "SIGINT")}
    assert "[" not in said["port gone"] and "went away (unplugged" in said["port gone"] and "did not come back" in said["port gone"]
    assert said["duration"].endswith("stopped after --duration")
    assert said["SIGINT"].endswith("stopped by Ctrl-C")


def test_an_unknown_option_is_said_by_the_command_it_was_given_to(tmp_path):
    """`stid fit ... --bogus` said "stid: error: unrecognized arguments" where every other
    mistake of a command says "stid fit: error: ..." (with that command's usage)."""
    r = _run("stid", "fit", tmp_path / "run.mcap", "--vehicle", tmp_path / "car.toml", "--bogus")
    _check_one_clear_line(r, "stid fit: error: unrecognized arguments: --bogus")
    assert "usage: stid fit" in r.stderr
