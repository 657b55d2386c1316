"""stid-log --live against the simulated car in real time: the page in a real browser
(headless Chromium) follows the run without a reload; a reconnect mid-run is said and
the view goes on; under a full CPU load the logger loses no more with the view than
without it."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from conftest import REPO, tool
from test_logger_e2e import Sim

CAR = REPO / "docs" / "examples" / "rc8.toml"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get_json(url: str):
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return json.loads(r.read())
    except (urllib.error.URLError, ConnectionError, TimeoutError, json.JSONDecodeError):
        return None


def live_logger(port, out, *args):
    return subprocess.Popen([tool("stid-log"), port, "-o", str(out), "--reconnect-timeout", "1", "--live",
                             "--vehicle", str(CAR), *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def summary(err: str) -> dict:
    """The logger's closing line: frames lost on the link, samples missing (overruns)."""
    line = [x for x in err.splitlines() if " samples, " in x and " lost, " in x][-1]
    lost = int(re.search(r"(\d+) lost,", line).group(1))
    missing = int(re.search(r"(\d+) samples missing", line).group(1))
    samples = int(re.search(r": (\d+) samples,", line).group(1))
    return {"lost": lost, "missing": missing, "samples": samples, "line": line}


def _page_has_shown_the_run(acks: list) -> bool:
    """Enough to judge the page by: five updates or more, over 5 s of data or more, the last
    with the table's three rows, the precision plot's points and a verdict."""
    return (len(acks) >= 5 and acks[-1]["seconds"] > acks[0]["seconds"] + 5 and acks[-1]["rows"] == 3
            and acks[-1]["points"] >= 3 and ("done" in acks[-1]["verdict"] or "lacking" in acks[-1]["verdict"]))


@pytest.mark.skipif(CHROMIUM is None, reason="needs a real browser: Debian's chromium (apt-get install chromium); "
                                             ".ci/run installs it")
def test_the_live_page_follows_the_run_in_a_real_browser_without_reload(tmp_path):
    """The car drives up to 40 s; once the page has shown enough the logger is stopped with
    Ctrl-C, as a user watching the page would. A browser slow to start on a loaded machine gets
    the time it needs, where a run of fixed length once ended before the page had drawn
    anything (CI, 2026-11-27). (Not the car: a simulator stopped mid-frame cuts its last frame,
    as a car switched off does, and the logger rightly counts it lost.)"""
    port = free_port()
    sim = Sim("--duration", 40, "--speed", 4, "--speed-profile", "track", "--effects", "actuator_lag")
    lg = live_logger(sim.port, tmp_path / "run.mcap", "--duration", 90, "--web", port, "--every", 1)
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + 20
    while get_json(url + "state") is None:
        assert time.monotonic() < deadline and lg.poll() is None, "the live view's page never answered"
        time.sleep(0.2)
    browser_err = tmp_path / "chromium.err"
    with open(browser_err, "wb") as err_file:
        browser = subprocess.Popen([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                                    "--disable-background-networking", "--no-first-run",
                                    f"--user-data-dir={tmp_path / 'chromium'}", url],
                                   stdout=subprocess.DEVNULL, stderr=err_file)
    seen: dict = {}  # view id -> the updates it said it drew, in order
    last_state = None
    t0, trace = time.monotonic(), []  # (s since the browser started, the newest update, what each page showed)
    try:
        while sim.proc.poll() is None:
            time.sleep(0.5)
            viewers = get_json(url + "viewers") or {}
            for view, ack in viewers.items():
                if not seen.get(view) or seen[view][-1]["seq"] != ack["seq"]:
                    seen.setdefault(view, []).append(ack)
            last_state = get_json(url + "state") or last_state
            trace.append((round(time.monotonic() - t0, 1), (last_state or {}).get("seq"),
                          {v[:6]: a["seq"] for v, a in viewers.items()}))
            if len(seen) == 1 and _page_has_shown_the_run(next(iter(seen.values()))):
                lg.send_signal(signal.SIGINT)
                break
    finally:
        browser.terminate()
        browser.wait(timeout=10)
    _, err = lg.communicate(timeout=90)
    sim.proc.terminate()
    sim.proc.wait(timeout=10)
    said = (f"what the page showed, every 0.5 s (s, newest update, per page): {trace}\n"
            f"chromium's exit code {browser.returncode}; its last words: "
            f"{browser_err.read_text(errors='replace')[-1500:]}")
    assert lg.returncode == 0, f"{err}\n{said}"
    assert len(seen) == 1, f"one page load, never reloaded: {list(seen)}\n{said}"
    acks = next(iter(seen.values()))
    seqs = [a["seq"] for a in acks]
    assert seqs == sorted(seqs), f"{seqs}\n{said}"
    assert _page_has_shown_the_run(acks), f"{acks[-1]}\n{said}"
    assert last_state["seq"] - acks[-1]["seq"] <= 2, f"the page keeps up with the updates\n{said}"
    s = summary(err)
    assert s["lost"] == 0 and s["missing"] == 0, f"{s['line']}\n{said}"


def test_a_reconnect_mid_run_is_said_and_the_view_goes_on(tmp_path):
    link = tmp_path / "car"
    sim = Sim("--duration", 10, "--speed", 4, "--disconnect-at", 5, "--reconnect-after", 1.5, "--link", link)
    lg = live_logger(link, tmp_path / "run.mcap", "--duration", 60, "--every", 1, "--reconnect-timeout", 3)
    sim.wait()
    out, err = lg.communicate(timeout=90)
    assert lg.returncode == 0, err
    went = out.find("went away")
    back = out.find("is back")
    assert 0 <= went < back, out[-3000:]
    # updates after the replug, on more data than before it
    before = [float(m) for m in re.findall(r"^\[\s*([\d.]+) s\] stid live", out[:went], re.M)]
    after = [float(m) for m in re.findall(r"^\[\s*([\d.]+) s\] stid live", out[back:], re.M)]
    assert before and after and max(after) > max(before) + 3, (before, after)
    assert "Traceback" not in out + err


def _hogs(n: int):
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


@pytest.mark.parametrize("seconds", [8, pytest.param(90, marks=pytest.mark.slow)])
def test_under_full_cpu_load_the_logger_loses_no_more_with_the_live_view(tmp_path, seconds):
    """Every core busy (a spinning process per core, at the loggers' priority); three
    simulated cars driving at once, two logged plainly, one with --live. The view (niced,
    in its own process) must not cost its logger a sample: its loss is within what the two
    plain loggers, under the same load at the same time, differ by. (The slow version drives
    long enough for the view's updates to cost most: 90 s of data, a background diagnosis.)

    A loss under full load is a chance event: with the plain loggers at 0 and 0 the rule allows
    the live one none, and it once lost 2 frames while a second test suite ran beside this one.
    So a trial the live logger loses is driven once more: a view that costs its logger samples
    loses both, a chance loss seldom twice."""
    lines, held = [], False
    for trial in range(2):
        loss, said = _loss_under_load(tmp_path / f"trial{trial}", seconds)
        lines.append(said)
        a, b = loss["plain_a"], loss["plain_b"]
        held = loss["live"] <= max(a, b) + abs(a - b)
        if held:
            break
    assert held, "the live logger lost more than the plain ones in two trials:\n" + "\n\n".join(lines)


def _loss_under_load(d, seconds):
    d.mkdir()
    hogs = []
    try:
        sims = {m: Sim("--duration", seconds, "--speed", 4, "--seed", 3, "--effects", "actuator_lag")
                for m in ("plain_a", "plain_b", "live")}
        loggers = {}
        for mode, sim in sims.items():
            if mode == "live":
                loggers[mode] = live_logger(sim.port, d / f"{mode}.mcap", "--duration", 60, "--every", 1)
            else:
                loggers[mode] = subprocess.Popen([tool("stid-log"), sim.port, "-o", str(d / f"{mode}.mcap"),
                                                  "--duration", "60", "--reconnect-timeout", "1"],
                                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # the load from here, while the loggers start and log: the three cars' own start-up under it
        # tested nothing, and took the rest of the test suite's two cores for ~15 s more
        hogs = _hogs(os.cpu_count() or 2)
        for sim in sims.values():
            sim.wait(timeout=seconds + 120)
        results = {}
        for mode, lg in loggers.items():
            out, err = lg.communicate(timeout=120)
            assert lg.returncode == 0, err
            results[mode] = summary(err)
            if mode == "live":
                assert "stid live" in out  # the view ran (and updated) while its logger logged
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    loss = {m: r["lost"] * 10 + r["missing"] for m, r in results.items()}  # (a frame holds 10 samples)
    lines = "\n".join(f"{m}: {r['line']}" for m, r in results.items())
    print(lines)
    return loss, lines


def test_ctrl_c_stops_the_logger_and_the_view_ends_on_the_finished_file(tmp_path):
    """Ctrl-C (SIGINT) reaches the logger; the view, in a session of its own, is not
    stopped by it: the logger finishes the file, and the view's last update is on it."""
    import signal

    sim = Sim("--duration", 60, "--speed", 4)
    try:
        lg = live_logger(sim.port, tmp_path / "run.mcap", "--every", 1)
        time.sleep(10)
        lg.send_signal(signal.SIGINT)
        out, err = lg.communicate(timeout=90)
    finally:
        sim.proc.kill()
        sim.proc.communicate()
    assert lg.returncode == 0, err
    blocks = out.split("] stid live ")
    assert len(blocks) >= 3 and "[file finished]" in blocks[-1], out[-2000:]
    assert summary(err)["line"].endswith("stopped by Ctrl-C"), err


def test_a_live_view_that_ends_is_said_and_the_recording_goes_on(tmp_path):
    """The live view could not serve its page (the port held by another program): it ended at once,
    and the logger recorded on without a word, the driver watching for a page that never came."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        sim = Sim("--duration", 5, "--speed", 4)
        lg = live_logger(sim.port, tmp_path / "run.mcap", "--duration", 60, "--web", port)
        sim.wait()
        _, err = lg.communicate(timeout=90)
    assert lg.returncode == 0, err
    assert f"--web {port}: cannot serve" in err, err  # the view's own reason
    assert "the live view ended (exit 2); recording goes on" in err, err
    assert summary(err)["samples"] > 1000, err  # nothing of the run was lost to it
