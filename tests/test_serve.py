"""stid serve: commands run in a warm server say, print and exit exactly as they do alone; only a
server of the same code takes them; Ctrl-C and a killed client reach the command; nothing is
left running. Whole processes, as a user runs them (the console script `stid`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests.conftest import REPO, tool
from tests.simdata import sim_run

STID = tool("stid")
VEHICLE = REPO / "docs" / "examples" / "rc8.toml"
pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="Unix sockets with SCM_RIGHTS, /proc")


def _env(serve_dir: str, **more) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "STID_NO_SERVER"}  # (conftest's: every other test runs cold)
    env["STID_SERVE_DIR"] = serve_dir
    env.update(more)
    return env


def _children(pid: int) -> list[int]:
    out = []
    for p in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(p))
    return out


class Server:
    def __init__(self, serve_dir: str):
        self.dir = serve_dir
        self.log = Path(serve_dir + ".log")
        self.proc = subprocess.Popen([STID, "serve", "--idle", "5"], env=_env(serve_dir), stdout=subprocess.DEVNULL,
                                     stderr=self.log.open("w"))
        deadline = time.monotonic() + 60
        while "ready" not in self.log.read_text():
            assert self.proc.poll() is None, self.log.read_text()
            assert time.monotonic() < deadline, "stid serve did not get ready in 60 s"
            time.sleep(0.1)

    def served(self) -> list[str]:
        return [ln for ln in self.log.read_text().splitlines() if " ended with " in ln]

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=20)


@pytest.fixture(scope="module")
def server():
    d = tempfile.mkdtemp(prefix="stid-serve-", dir="/tmp")  # short: a Unix socket's path has ~100 bytes
    s = Server(os.path.join(d, "s"))
    yield s
    s.stop()
    assert not _children(s.proc.pid)


@pytest.fixture(scope="module")
def run_file(simdir):
    return sim_run(simdir, effects=("actuator_lag",), duration=20.0)


def _stid(args, serve_dir, cwd=None, **env):
    return subprocess.run([STID, *map(str, args)], env=_env(serve_dir, **env), cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def test_a_served_command_prints_and_exits_as_it_does_alone(server, run_file, tmp_path):
    """The same bytes on stdout and stderr and the same exit status, warm and cold; a relative
    path is read from the client's directory and a written file gets the client's umask."""
    before = len(server.served())
    args = ["diagnose", run_file.name, "--vehicle", VEHICLE, "--json"]
    warm = _stid(args, server.dir, cwd=run_file.parent)
    assert len(server.served()) == before + 1, "the command did not run in the server"
    cold = _stid(args, server.dir, cwd=run_file.parent, STID_NO_SERVER="1")
    assert len(server.served()) == before + 1
    assert (warm.returncode, warm.stdout, warm.stderr) == (cold.returncode, cold.stdout, cold.stderr)
    assert warm.returncode == 0 and '"candidates"' in warm.stdout

    out = tmp_path / "run.csv"
    old = os.umask(0o077)
    try:
        r = subprocess.run([STID, "export", run_file, "--csv", out], env=_env(server.dir), capture_output=True,
                           text=True, timeout=120)
    finally:
        os.umask(old)
    assert r.returncode == 0, r.stderr
    assert len(server.served()) == before + 2
    assert out.stat().st_mode & 0o777 == 0o600  # the client's umask, not the server's


def test_a_user_error_is_one_line_and_exit_2_warm_as_cold(server, run_file):
    before = len(server.served())
    for args in (["fit", "missing.mcap", "--vehicle", VEHICLE],
                 ["fit", run_file, "--vehicle", VEHICLE, "--model", "bicycle+actuator_lagg"],
                 ["diagnose", run_file],  # argparse's usage error: exit 2 with the usage
                 ["fit", run_file, "--vehicle", VEHICLE, "--method", "nope"]):
        warm, cold = _stid(args, server.dir), _stid(args, server.dir, STID_NO_SERVER="1")
        assert (warm.returncode, warm.stdout, warm.stderr) == (cold.returncode, cold.stdout, cold.stderr), args
        assert warm.returncode == 2 and "Traceback" not in warm.stderr
    assert len(server.served()) == before + 4


def test_a_users_effect_file_is_read_by_each_command_not_by_the_server(server, run_file, tmp_path):
    """STID_EFFECTS is the command's: the server never loads the catalogue, so an effect file a
    user has just written (or broken) is the one a served command uses."""
    mine = tmp_path / "my_effect.py"
    mine.write_text((REPO / "docs" / "examples" / "accel_scale.py").read_text())
    args = ["fit", run_file, "--vehicle", VEHICLE, "--model", "bicycle+accel_scale", "--json"]
    before = len(server.served())
    warm, cold = (_stid(args, server.dir, STID_EFFECTS=str(mine), **more) for more in ({}, {"STID_NO_SERVER": "1"}))
    assert warm.returncode == 0 and (warm.stdout, warm.stderr) == (cold.stdout, cold.stderr)
    mine.write_text("this is not python\n")
    warm, cold = (_stid(args, server.dir, STID_EFFECTS=str(mine), **more) for more in ({}, {"STID_NO_SERVER": "1"}))
    assert warm.returncode == 2 and "my_effect.py failed to load" in warm.stderr
    assert (warm.returncode, warm.stderr) == (cold.returncode, cold.stderr)
    assert len(server.served()) == before + 2


def test_only_a_server_of_the_same_code_and_environment_takes_a_command(server, run_file):
    before = len(server.served())
    r = _stid(["fit", run_file, "--vehicle", VEHICLE, "--json"], server.dir, NUMBA_OPT="2")  # read at import
    assert r.returncode == 0, r.stderr
    assert len(server.served()) == before, "a server imported with another NUMBA_ setting ran the command"
    r = _stid(["fit", run_file, "--vehicle", VEHICLE, "--json"], server.dir, STID_NO_SERVER="1")
    assert r.returncode == 0 and len(server.served()) == before
    r = _stid(["--help"], server.dir)
    assert r.returncode == 0 and len(server.served()) == before


def _nice(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[16])


def test_ctrl_c_and_a_killed_client_end_the_command_and_its_workers(server, run_file):
    """And the command runs at the client's priority (stid live niced its background diagnosis
    below the logger: in the server it must stay there)."""
    long_run = sim_run(run_file.parent, effects=("actuator_lag", "accel_offset"), duration=60.0, seed=3)
    for how in ("sigint", "kill"):
        before = len(server.served())
        p = subprocess.Popen([STID, "diagnose", long_run, "--vehicle", VEHICLE, "--peel"], env=_env(server.dir),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: os.nice(15) if how == "sigint" else None)
        deadline = time.monotonic() + 30
        while not [r for s in _children(server.proc.pid) for r in _children(s)]:  # supervisor, then runner
            assert time.monotonic() < deadline and p.poll() is None
            time.sleep(0.05)
        time.sleep(0.5)  # into the fits (the worker pool is running)
        runner = [r for s in _children(server.proc.pid) for r in _children(s)][0]
        assert _nice(runner) == (15 if how == "sigint" else _nice(server.proc.pid))
        p.send_signal(signal.SIGINT) if how == "sigint" else p.kill()
        out, err = p.communicate(timeout=60)
        if how == "sigint":
            assert p.returncode == 130 and err.strip().endswith("interrupted"), (p.returncode, err)
        else:  # killed as a cold command is: nothing more on the terminal (err is read to the runner's end)
            assert "interrupted" not in err, err
        deadline = time.monotonic() + 20
        while _children(server.proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _children(server.proc.pid), "the interrupted command (or its workers) still runs"
        status = "130" if how == "sigint" else "137"  # (137: killed, as a shell reports kill -9)
        assert server.served()[before:] and server.served()[-1].split(" ended with ")[1].startswith(status), how


def test_a_stale_socket_is_passed_by_and_a_second_server_refused(server, run_file, tmp_path):
    d = tempfile.mkdtemp(prefix="stid-stale-", dir="/tmp")
    os.chmod(d, 0o700)
    stale = _stid(["serve", "--stop"], d)  # nothing running: says so, exit 0
    assert stale.returncode == 0 and "no server" in stale.stderr
    # a socket file whose server was killed (-9): connect is refused, the command runs here
    fp = subprocess.run([sys.executable, "-c", "from stid.serve import fingerprint; print(fingerprint())"],
                        env=_env(d), capture_output=True, text=True, cwd=tmp_path).stdout.strip()
    import socket

    s = socket.socket(socket.AF_UNIX)
    s.bind(os.path.join(d, f"serve-{fp}.sock"))
    s.close()
    r = _stid(["fit", run_file, "--vehicle", VEHICLE, "--json"], d)
    assert r.returncode == 0 and '"params"' in r.stdout, r.stderr

    second = _stid(["serve"], server.dir)
    assert second.returncode == 2 and second.stderr.count("\n") == 1 and "already running" in second.stderr


def test_a_directory_others_may_enter_is_refused(tmp_path):
    d = tempfile.mkdtemp(prefix="stid-open-", dir="/tmp")
    os.chmod(d, 0o755)
    r = _stid(["serve"], d)
    assert r.returncode == 2 and "mode 700" in r.stderr and "Traceback" not in r.stderr


def test_stop_ends_every_server_of_this_user(tmp_path):
    s = Server(os.path.join(tempfile.mkdtemp(prefix="stid-stop-", dir="/tmp"), "s"))
    try:
        r = _stid(["serve", "--stop"], s.dir)
        assert r.returncode == 0 and "stopped 1 server" in r.stderr
        # gone when --stop returns (a command typed next must not find its socket)
        assert not [n for n in os.listdir(s.dir) if n.endswith(".sock")]
        s.proc.wait(timeout=20)
        assert "stopped (stid serve --stop)" in s.log.read_text()
    finally:
        s.stop()


def test_a_connection_that_sends_nothing_holds_up_no_command(server, run_file):
    """The server read each request itself, with a 5 s timeout: a process of the same user that
    connected and sent nothing held the next command up for those 5 s."""
    import socket

    path = next(os.path.join(server.dir, n) for n in os.listdir(server.dir) if n.endswith(".sock"))
    before = len(server.served())
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as silent:
        silent.connect(path)
        t0 = time.monotonic()
        r = _stid(["fit", "missing.mcap", "--vehicle", VEHICLE], server.dir)
        took = time.monotonic() - t0
    assert r.returncode == 2 and len(server.served()) == before + 1, r.stderr
    assert took < 3.0, took  # a served user error takes ~0.1 s; the silent one held it 5 s


def _state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return "gone"


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except FileNotFoundError:
        return "gone"


def test_ctrl_z_stops_the_command_and_fg_continues_it(server, run_file):
    """A shell's Ctrl-Z stops the command it runs: the client, and with it the served command
    and its workers (they went on drawing over the prompt); fg continues all of them."""
    long_run = sim_run(run_file.parent, effects=("actuator_lag", "accel_offset"), duration=60.0, seed=3)
    # a job of its own, as a shell starts it: in an orphaned process group (as pytest-xdist's worker's
    # can be) the kernel discards a stop by SIGTSTP, and the client continues at once and its command
    # with it (that path is the test below)
    p = subprocess.Popen([STID, "diagnose", long_run, "--vehicle", VEHICLE, "--peel", "--json"], env=_env(server.dir),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, process_group=0)
    deadline = time.monotonic() + 30
    while not [r for s in _children(server.proc.pid) for r in _children(s)]:
        assert time.monotonic() < deadline and p.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)
    runner = [r for s in _children(server.proc.pid) for r in _children(s)][0]
    p.send_signal(signal.SIGTSTP)
    deadline = time.monotonic() + 10

    def states():  # the client, the command and every process it has now
        return {q: _state(q) for q in [p.pid, runner] + _children(runner)}

    while set(states().values()) != {"T"} and time.monotonic() < deadline:
        time.sleep(0.05)
    seen = states()
    assert set(seen.values()) == {"T"}, {q: (st, _cmdline(q)) for q, st in seen.items()}
    assert len(seen) >= 3  # the client, the command, and its workers
    p.send_signal(signal.SIGCONT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 0 and '"steps"' in out, err

    # an orphaned process group (a session of its own here): the kernel discards the client's stop, so
    # the command is stopped and continued at once, and ends as it would have (it stayed stopped for
    # ever when the continue arrived in the same read as the stop)
    p = subprocess.Popen([STID, "diagnose", long_run, "--vehicle", VEHICLE, "--peel", "--json"], env=_env(server.dir),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 30
    while not [r for s in _children(server.proc.pid) for r in _children(s)]:
        assert time.monotonic() < deadline and p.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)
    for _ in range(5):
        p.send_signal(signal.SIGTSTP)
        time.sleep(0.1)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 0 and '"steps"' in out, err


def test_a_killed_server_leaves_no_socket_that_answers(server, run_file, tmp_path):
    """Its commands' processes held the listening socket open: once the server was killed, a
    command connected there and waited for ever (Ctrl-C did not end it). Now they do not hold it,
    and a command runs cold; one whose server never takes it says so and ends on Ctrl-C."""
    own = Server(os.path.join(tempfile.mkdtemp(prefix="stid-kill-", dir="/tmp"), "s"))
    try:
        p = subprocess.Popen([STID, "report", run_file, "--vehicle", VEHICLE, "-o", tmp_path / "rep"],
                             env=_env(own.dir), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while not [r for s in _children(own.proc.pid) for r in _children(s)]:
            assert time.monotonic() < deadline and p.poll() is None
            time.sleep(0.05)
        own.proc.kill()
        own.proc.wait()
        r = _stid(["fit", run_file, "--vehicle", VEHICLE, "--json"], own.dir)  # no server: runs here
        assert r.returncode == 0 and '"params"' in r.stdout, r.stderr
        p.communicate(timeout=120)  # the command the server had taken still ends as it would
        assert p.returncode == 0

        # a server that is stopped (SIGSTOP) takes nothing: the command says so and Ctrl-C ends it
        own2 = Server(own.dir)
        os.kill(own2.proc.pid, signal.SIGSTOP)
        try:
            # (to files: the request waiting in the stopped server's socket holds the client's stdout and
            # stderr open, and a pipe's reader would wait for their end until the server took it)
            err_file = tmp_path / "err.txt"
            with open(err_file, "w") as err_f:
                q = subprocess.Popen([STID, "fit", run_file, "--vehicle", VEHICLE], env=_env(own.dir),
                                     stdout=subprocess.DEVNULL, stderr=err_f)
                time.sleep(6)
                q.send_signal(signal.SIGINT)
                q.wait(timeout=20)
            err = err_file.read_text()
            assert q.returncode == 130 and "has not taken this command in 5 s" in err and "Traceback" not in err
        finally:
            os.kill(own2.proc.pid, signal.SIGCONT)
            own2.stop()
    finally:
        own.stop()


def test_a_closed_stdout_runs_the_command_here_not_in_the_server(server, run_file):
    before = len(server.served())
    r = subprocess.run(f"{STID} fit {run_file} --vehicle {VEHICLE} --json >&-", shell=True, env=_env(server.dir),
                       capture_output=True, text=True, timeout=120)
    assert len(server.served()) == before
    assert "Traceback" not in r.stderr, r.stderr


def test_messages_that_arrive_together_are_each_read():
    """One read brought two frames (Ctrl-Z's stop and the continue sent at once where the kernel
    discards the client's own stop; a quick command's 'started' and 'exit'), and the second was
    dropped: a fresh clone's CI run left a command stopped for ever."""
    import socket

    from stid.serve import _Messages, _send_msg

    a, b = socket.socketpair()
    with a, b:
        for doc in ({"signal": 19}, {"signal": 18}, {"exit": 0}):
            _send_msg(a, doc)
        time.sleep(0.05)  # all three in b's buffer before the first read
        reader = _Messages(b)
        assert [reader.next()[0] for _ in range(3)] == [{"signal": 19}, {"signal": 18}, {"exit": 0}]
        a.close()
        assert reader.next() == (None, [])


def test_ctrl_c_while_the_command_looks_for_a_server_says_interrupted(monkeypatch, capsys):
    """Ctrl-C in a command's first tenth of a second (looking for a server, building the parser:
    before main_here's own handler) printed Python's KeyboardInterrupt traceback."""
    import stid.cli
    import stid.serve

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr(stid.serve, "run_in_server", interrupted)
    monkeypatch.setattr(sys, "argv", ["stid", "diagnose", "run.mcap"])
    assert stid.cli.main() == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_the_live_views_background_diagnosis_is_served(server, run_file, monkeypatch):
    """stid live's background diagnosis started `python -m stid.cli`, whose sys.path (the working
    directory first) is not the console script's: no server ever answered it, and every try
    loaded numpy, scipy and numba at the lowest priority. It runs the `stid` script now."""
    from stid.live.diagnosis import BackgroundDiagnosis

    monkeypatch.delenv("STID_NO_SERVER", raising=False)
    monkeypatch.setenv("STID_SERVE_DIR", server.dir)
    before = len(server.served())
    bd = BackgroundDiagnosis(run_file, str(VEHICLE), "bicycle")
    bd.poll(20.0)
    assert bd.proc is not None
    bd.proc.wait(timeout=120)
    text = bd.poll(20.0)
    assert text and text.startswith("diagnosis:") and "stid diagnose" in text, text
    assert len(server.served()) == before + 1, "the diagnosis did not run in the server"


def test_the_fingerprint_counts_every_kind_of_source_a_command_runs(tmp_path, monkeypatch):
    """A server must not outlive the code it loaded: a page, a car file, the C loop's build, and the
    C loop's source, whose edit retires the build (stid.models.recursion) until make runs."""
    from stid import serve

    for f in ("a.py", "page.html", "car.toml", "_ltv_recursion.so", "ltv_recursion.c"):
        (tmp_path / f).write_text("")
    monkeypatch.setattr(serve, "_source_dirs", lambda: [str(tmp_path)])
    for f in ("a.py", "page.html", "car.toml", "_ltv_recursion.so", "ltv_recursion.c"):
        before = serve.fingerprint()
        st = os.stat(tmp_path / f)
        os.utime(tmp_path / f, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
        assert serve.fingerprint() != before, f"{f} edited, the server's fingerprint unchanged"
