"""A stand-in for mpremote in front of a simulated board, for the `stid flash` tests.

The board is a folder (env FAKE_BOARD) whose files are the board's filesystem and whose
`.board.json` says what the board is: {"platform": "rp2", "version": [1, 26, 0],
"heap": 190000, "fs_size": 868352, "answer": null, "cp_fails_after": null,
"statvfs": true}; "statvfs": false is a port without os.statvfs (the free space unknown).

- `connect DEV exec SCRIPT` runs SCRIPT on the real MicroPython unix port in the
  folder, with a heap of `heap` bytes (so gc.mem_free() is measured, not told). The
  unix port cannot pretend to be another port, so three names are replaced in the
  script before it runs: `sys.platform`, `sys.implementation.version[:3]` and
  `os.statvfs("/")` (the filesystem of `fs_size` bytes, 4 kB blocks, less the files
  on it). `answer`, when set, is printed instead (a board that answers garbage).
  Importing the compiled firmware: a `.mpy` on the board whose header names another
  architecture than the board's cannot be imported (as on a board); one that can is
  run from an x64 build of the same module, with hil_sim/board's `machine` beside it.
- `connect DEV fs cp SRC... :` copies; a file that does not fit the filesystem is
  written in part and the command fails as mpremote does ("cp: ENOSPC: ..."); with
  `cp_fails_after` = n, the copy stops after n files with a transport error (a cable
  pulled half way), the (n+1)th file half written.
- `connect DEV reset` does nothing.
Every call is appended to `.calls` (one line each: the arguments after DEV). FAKE_CACHE,
when set, is a folder for what every board of a test session can share (x64 builds,
the stimulus the simulated `machine` reads).
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIRMWARE = REPO / "firmware" / "micropython"
BOARD_SIM = REPO / "hil_sim" / "board"
ARCH_CODE = {"rp2": 4, "esp32": 10}  # the .mpy header's architecture (armv6m, xtensawin)
BLOCK = 4096


def _bin(name):
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else name


def _files(board: Path):
    return [p for p in board.iterdir() if p.is_file() and not p.name.startswith(".")]


def _used(board: Path) -> int:
    return sum(-(-p.stat().st_size // BLOCK) * BLOCK for p in _files(board))


def _shadow(board: Path, state: dict) -> Path:
    # what the board can import: x64 builds of the .mpy files its architecture accepts
    # (rebuilt only for the files that changed since the last call: .x64/.made)
    shadow = board / ".x64"
    shadow.mkdir(exist_ok=True)
    made_file = shadow / ".made"
    made = json.loads(made_file.read_text()) if made_file.exists() else {}
    now = {}
    for f in _files(board):
        if f.suffix not in (".mpy", ".py"):
            continue
        data = f.read_bytes()
        key = hashlib.sha256(data).hexdigest()
        now[f.name] = key
        if made.get(f.name) == key:
            continue
        src = FIRMWARE / (f.stem + ".py")
        ok = len(data) > 4 and data[:2] == b"M\x06" and (data[2] >> 2) in (0, ARCH_CODE[state["platform"]])
        if f.suffix == ".mpy" and ok and src.exists():
            # x64 builds are shared by every board of the session (FAKE_CACHE), by source
            cache = Path(os.environ.get("FAKE_CACHE", board)) / ("x64-" + hashlib.sha256(src.read_bytes()).hexdigest())
            if not cache.exists():
                subprocess.run([_bin("mpy-cross"), "-march=x64", "-o", str(cache), str(src)], check=True)
            (shadow / f.name).write_bytes(cache.read_bytes())
        else:
            (shadow / f.name).write_bytes(data)  # a bad .mpy fails to import, as on the board
    for name in set(made) - set(now):
        (shadow / name).unlink(missing_ok=True)
    made_file.write_text(json.dumps(now))
    return shadow


def _stimulus(board: Path, state: dict) -> Path:
    path = Path(os.environ.get("FAKE_CACHE", board)) / f".{state['platform']}.stim.bin"
    if not path.exists():
        sys.path.insert(0, str(REPO / "tests"))
        sys.path.insert(0, str(REPO))
        from conftest import simple_stimulus
        simple_stimulus(path, board="pico" if state["platform"] == "rp2" else "esp32", seconds=0.2)
    return path


def do_exec(board: Path, state: dict, script: str) -> int:
    if state.get("answer") is not None:
        sys.stdout.write(state["answer"])
        return 0
    free = state["fs_size"] - _used(board)
    statvfs = (BLOCK, BLOCK, state["fs_size"] // BLOCK, free // BLOCK, free // BLOCK, 0, 0, 0, 0, 255)
    script = (script.replace("sys.platform", repr(state["platform"]))
              .replace("sys.implementation.version[:3]", repr(tuple(state["version"])))
              .replace('os.statvfs("/")', repr(statvfs) if state.get("statvfs", True) else 'os.no_statvfs("/")'))
    # the board's own folder is its filesystem, not its import path (see _shadow)
    script = "import sys\nsys.path[:] = [p for p in sys.path if p]\n" + script
    env = dict(os.environ, MICROPYPATH=f"{_shadow(board, state)}:{BOARD_SIM}",
               STID_SIM_STIMULUS=str(_stimulus(board, state)))
    proc = subprocess.run([_bin("micropython"), "-X", f"heapsize={state['heap']}", "-c", script], cwd=board,
                          env=env, capture_output=True, text=True)
    sys.stdout.write(proc.stdout + proc.stderr)  # mpremote shows the board's traceback on stdout
    return 1 if proc.returncode else 0


def do_cp(board: Path, state: dict, srcs) -> int:
    for n, src in enumerate(srcs):
        data = Path(src).read_bytes()
        dest = board / Path(src).name
        if state.get("cp_fails_after") is not None and n >= state["cp_fails_after"]:
            dest.write_bytes(data[: len(data) // 2])
            sys.stderr.write("mpremote: Error with transport:\nfailed to access /dev/ttyACM0\n")
            return 1
        old = -(-dest.stat().st_size // BLOCK) * BLOCK if dest.exists() else 0
        room = state["fs_size"] - (_used(board) - old)
        if len(data) > room:
            dest.write_bytes(data[: max(room, 0)])
            sys.stderr.write("mpremote: cp: ENOSPC: No space left on device.\n")
            return 1
        dest.write_bytes(data)
    return 0


def main(argv) -> int:
    board = Path(os.environ["FAKE_BOARD"])
    state = json.loads((board / ".board.json").read_text())
    assert argv[0] == "connect", argv
    rest = argv[2:]
    with open(board / ".calls", "a") as f:
        f.write(" ".join(rest)[:200].replace("\n", "\\n") + "\n")
    if rest[0] == "exec":
        return do_exec(board, state, rest[1])
    if rest[:2] == ["fs", "cp"]:
        assert rest[-1] == ":", rest
        return do_cp(board, state, rest[2:-1])
    if rest[0] == "reset":
        return 0
    sys.stderr.write(f"fake mpremote: {rest[0]} is not modelled\n")
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
