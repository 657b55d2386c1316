import os

# one BLAS thread in every test process and the tools it starts (see stid/__init__.py)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# every command a test runs runs cold, here: a developer's warm server (stid serve) is not the code
# under test's concern (tests/test_serve.py starts its own)
os.environ["STID_NO_SERVER"] = "1"
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
FIRMWARE = REPO / "firmware" / "micropython"
BOARD = REPO / "hil_sim" / "board"
MP_TESTS = Path(__file__).resolve().parent / "firmware_mp"
VECTORS = REPO / "firmware" / "vectors" / "vectors.json"


# Tests that run a logger in real time on pseudo-terminals: with `make test`'s parallel workers
# (pytest-xdist, --dist loadgroup) they share one worker and so run one after another, as a user
# runs one car, one logger and one live view; the other worker's fits load the CPU meanwhile.
REAL_TIME_PTY_MODULES = ("test_live_realtime", "test_log_port", "test_logger_e2e")


@pytest.hookimpl(tryfirst=True)  # before xdist's, which reads the group into the test's id: this
def pytest_collection_modifyitems(config, items):  # conftest is registered after it, so runs after it
    for item in items:
        if item.module.__name__.rsplit(".", 1)[-1] in REAL_TIME_PTY_MODULES:
            item.add_marker(pytest.mark.xdist_group("real-time-pty"))


def _processes_naming(text: str) -> list[tuple[int, str]]:
    """Live processes whose command line contains ``text`` (Linux /proc)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
            with open(f"/proc/{pid}/stat") as f:
                zombie = f.read().rsplit(")", 1)[1].split()[0] == "Z"
        except OSError:
            continue
        if text in cmd and not zombie and int(pid) != os.getpid():
            found.append((int(pid), cmd.strip()))
    return found


@pytest.fixture(autouse=True)
def _no_logger_outlives_its_test(request):
    """A logger (or simulator, or live view) left running by a real-time test would hold a
    pty whose number the next test's simulator gets again, and that test's logger would find
    the port "in use". Each is stopped here, and the test that left it fails."""
    if request.node.module.__name__.rsplit(".", 1)[-1] not in REAL_TIME_PTY_MODULES:
        yield
        return
    if hasattr(request.config, "workerinput") and request.config.getvalue("loadgroup"):
        # xdist puts the group into the test's id; where it does not, the group is ignored
        # without a word (pytest-dev/pytest-xdist#1386, with pytest 9.2) and these tests clash
        assert request.node.nodeid.endswith("@real-time-pty"), (
            "pytest-xdist's --dist loadgroup does not group the real-time tests with this pytest: "
            "see pyproject.toml's pin of pytest")
    tmp = request.getfixturevalue("tmp_path")
    yield
    import signal
    import time

    deadline = time.monotonic() + 5  # a process a test has just stopped may take a moment to go
    while (left := _processes_naming(str(tmp))) and time.monotonic() < deadline:
        time.sleep(0.2)
    for pid, _ in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    assert not left, f"processes left running by this test: {left}"


def tool(name: str) -> str:
    """A console tool of this environment (the venv's bin, then PATH)."""
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else name


def run_micropython(script: Path, *args, stimulus: Path | None = None, board: bool = False,
                    timeout: float = 120) -> subprocess.CompletedProcess:
    path = [str(MP_TESTS), str(FIRMWARE)]
    if board:
        path.insert(0, str(BOARD))
    env = dict(os.environ, MICROPYPATH=":".join(path))
    if stimulus is not None:
        env["STID_SIM_STIMULUS"] = str(stimulus)
    return subprocess.run([tool("micropython"), "-X", "heapsize=32M", str(script), *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=timeout)


def simple_stimulus(path: Path, board: str = "pico", seconds: float = 3.0, fs: int = 5000,
                    start_ticks: int = 0, stalls=(), four_wheels: bool = False):
    """A small stimulus with recognisable signals on every pin of the board (and, with
    ``four_wheels``, four hall sensors at slightly different rates)."""
    from hil_sim.stimulus import Stimulus

    n = int(seconds * fs)
    t = np.arange(n) / fs
    if board == "pico":
        pins = {26: 1.65 + 0.2 * np.sin(2 * np.pi * 1.3 * t), 27: 1.65 + 0.4 * np.sin(2 * np.pi * 0.7 * t),
                28: 1.65 + 0.5 * np.sin(2 * np.pi * 2.1 * t)}
        steer_pin, hall_pin = 2, 3
    else:
        pins = {32: 1.65 + 0.2 * np.sin(t), 33: 1.65 + 1.0 * np.sin(2 * t), 34: 1.98 + 0 * t,
                35: 1.65 + 0.5 * np.sin(3 * t), 36: 1.2 + 0 * t}
        steer_pin, hall_pin = 25, 26
    periods = int(seconds * 50)
    steer = (1500 + 400 * np.sin(np.arange(periods) / 10)).astype(int)
    hall = np.arange(5_000, int(seconds * 1e6), 37_000)
    halls = None
    if four_wheels:
        hp = {"pico": {"fl": 4, "fr": 5, "rl": 3, "rr": 6}, "esp32": {"fl": 27, "fr": 14, "rl": 26, "rr": 13}}[board]
        halls = {k: (pin, np.arange(5_000 + 1000 * i, int(seconds * 1e6), 37_000 + 500 * i))
                 for i, (k, pin) in enumerate(hp.items())}
    st = Stimulus(board=board, fs_sig=fs, volts=pins, steer_us=steer, hall_t_us=hall,
                  steer_pin=steer_pin, hall_pin=hall_pin, start_ticks=start_ticks, stalls=list(stalls),
                  wheel_halls=halls)
    st.write(path)
    return st


@pytest.fixture
def stimulus_file(tmp_path):
    path = tmp_path / "stim.bin"
    simple_stimulus(path)
    return path


@pytest.fixture(scope="session")
def simdir(tmp_path_factory):
    """One directory of simulated runs shared by the whole session, and by its xdist workers
    (the parent of a worker's base directory is the session's; see simdata.py)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        d = tmp_path_factory.getbasetemp().parent / "sim"
        d.mkdir(exist_ok=True)
        return d
    return tmp_path_factory.mktemp("sim")


@pytest.fixture(scope="session")
def rc_vehicle():
    from stid.vehicle_file import load_vehicle

    return load_vehicle(REPO / "docs" / "examples" / "rc8.toml")


@pytest.fixture(scope="session")
def rc_vehicle_csv(rc_vehicle):
    """The reference car for the simulator's CSV files: a CSV carries no sensor chain, and the
    simulated sensors' outputs went through the ADXL335's 50 Hz and the LISY300AL's 88 Hz
    filters, so the user declares them in the vehicle file's [sensors] (an MCAP run's HELLO
    declares them itself)."""
    import dataclasses

    return dataclasses.replace(rc_vehicle, sensors={**rc_vehicle.sensors, "accel_bandwidth_hz": 50.0,
                                                    "gyro_bandwidth_hz": 88.0})
