"""A warm process the ``stid`` command runs in: ``stid serve``.

A cold ``stid diagnose`` spends 0.8-0.9 s of its ~1.8 s importing numpy, scipy and numba and
loading the compiled simulator before its first fit (docs/measurements.md); no choice of
code inside one process removes that. ``stid serve`` pays it once: it imports what the
commands use and waits. A ``stid`` command run while it waits hands its arguments, working
directory, environment, umask and terminal (stdin, stdout, stderr, passed as file
descriptors) to the server, which forks a copy of itself (already loaded) to run the
command there, and answers with its exit status. The output, the progress on the terminal,
Ctrl-C and the exit status are those of the command run alone.

Only a server running *the same code in the same environment* is used: its socket's name is
a fingerprint of the interpreter, ``sys.path``, the environment variables read at import
time, the modification times of stid's own source files and of the installed packages'
directories (``pip install`` changes them). Edit a file, or install a package, and commands
run cold again until the server is restarted; a server no command can use exits when idle.

The socket lives in a directory only its user can enter (``$XDG_RUNTIME_DIR/stid`` or
``/tmp/stid-UID``; ``STID_SERVE_DIR`` overrides it), and the server checks the peer's user
id on Linux. ``STID_NO_SERVER=1`` makes a command run cold whatever is running.

The command gets the client's priority (``nice``), not its resource limits (``ulimit``).

Process layout per command: the server accepts and forks a *supervisor*, which reads the
request, forks the *runner* (the command) and relays: Ctrl-C (and SIGTERM, SIGHUP)
from the client to the runner, the runner's exit status back, and a client that went away
(killed) as an interrupt to the runner. The server itself never waits on a command.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import struct
import sys
import time

# Commands that compute (and so gain ~0.8 s warm). Not `live` (long-running, its own threads and
# web server), `flash` (mpremote does the work), `repair` (a few file operations).
SERVED = frozenset({"fit", "diagnose", "compare", "report", "plan", "calibrate", "batch", "export"})
# Environment variables read when a module is imported or Python starts: a server started with
# other values than a command's would compute or print differently (threads, numba's options, the
# locale's encoding). An effect file's path (STID_EFFECTS) is read per command and needs no part here
IMPORT_TIME_ENV = ("PYTHON", "NUMBA_", "OPENBLAS_", "OMP_", "MKL_", "MPL", "NUMPY_", "SCIPY_", "LANG", "LC_")
DEFAULT_IDLE_S = 30 * 60
FORWARDED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# Modules the served commands import: loaded once in the server, shared by every runner
PRELOAD = ("numpy", "scipy.optimize", "scipy.special", "scipy.signal", "stid.cli", "stid.load", "stid.fit.fitting",
           "stid.diagnose", "stid.present", "stid.compare", "stid.calibrate", "stid.crlb", "stid.report",
           "stid.effects")


# ---------------------------------------------------------------- where, and which code


def socket_dir() -> str:
    d = os.environ.get("STID_SERVE_DIR")
    if not d:
        run = os.environ.get("XDG_RUNTIME_DIR")
        d = os.path.join(run, "stid") if run and os.path.isdir(run) else f"/tmp/stid-{os.getuid()}"
    return d


def _private_dir(d: str, create: bool) -> str | None:
    """``d`` if it is a directory of this user that no one else may enter (made so when
    ``create``), else None: a socket in a shared directory could be someone else's."""
    if create:
        if os.path.exists(d) and not os.path.isdir(d):
            from stid.errors import InputError

            raise InputError(f"{d} is a file, not a directory: set STID_SERVE_DIR to a directory (or unset it)")
        os.makedirs(d, mode=0o700, exist_ok=True)
    try:
        st = os.stat(d)
    except OSError:
        return None
    return d if st.st_uid == os.getuid() and not st.st_mode & 0o077 else None


def _source_dirs() -> list[str]:
    import importlib.util

    out = []
    for name in ("stid", "host", "hil_sim"):
        spec = importlib.util.find_spec(name)
        for loc in (spec.submodule_search_locations or []) if spec else []:
            out.append(loc)
    return out


def fingerprint() -> str:
    """Which code, in which environment: see the module's docstring. ~6 ms (a stat per file)."""
    import hashlib

    h = hashlib.sha256()
    h.update(repr((sys.executable, sys.version, sys.path, os.getuid())).encode())
    h.update(repr(sorted((k, v) for k, v in os.environ.items() if k.startswith(IMPORT_TIME_ENV))).encode())
    for entry in sys.path:  # installing, upgrading or removing a package changes its directory
        try:
            h.update(f"{entry}:{os.stat(entry or '.').st_mtime_ns}".encode())
        except OSError:
            pass
    for top in _source_dirs():
        for root, dirs, files in os.walk(top):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for f in sorted(files):
                if f.endswith((".py", ".html", ".toml", ".so", ".c")):  # (.c: a newer source retires its build)
                    p = os.path.join(root, f)
                    h.update(f"{p}:{os.stat(p).st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def _socket_in(d: str) -> str:
    """The socket of a server of this code and environment, in the directory ``d``."""
    return os.path.join(d, f"serve-{fingerprint()}.sock")


# ---------------------------------------------------------------- messages


def _send_msg(sock: socket.socket, doc: dict, fds=()) -> None:
    data = json.dumps(doc).encode()
    frame = struct.pack("!I", len(data)) + data
    if fds:
        sent = socket.send_fds(sock, [frame], list(fds))
        sock.sendall(frame[sent:])
    else:
        sock.sendall(frame)


class _Messages:
    """The framed messages arriving on one connection, in order. One read may bring more than one
    (a quick command's 'started' and 'exit'; Ctrl-Z's stop and the continue that follows it at once
    where the kernel discards the stop): what follows the first is kept for the next."""

    def __init__(self, sock: socket.socket):
        self.sock, self.buf = sock, b""

    def next(self, max_fds: int = 0):
        """(doc, fds) of the next message, or (None, []) at end of stream."""
        fds: list[int] = []
        while len(self.buf) < 4 or len(self.buf) < 4 + struct.unpack("!I", self.buf[:4])[0]:
            if max_fds and not fds:
                chunk, got, _, _ = socket.recv_fds(self.sock, 65536, max_fds)
                fds.extend(got)
            else:
                chunk = self.sock.recv(65536)
            if not chunk:
                for fd in fds:
                    os.close(fd)
                return None, []
            self.buf += chunk
        n = struct.unpack("!I", self.buf[:4])[0]
        doc, self.buf = json.loads(self.buf[4:4 + n]), self.buf[4 + n:]
        return doc, fds


def _peer_is_us(conn: socket.socket) -> bool:
    cred = getattr(socket, "SO_PEERCRED", None)
    if cred is None:  # (not Linux: the directory's permissions are the guard)
        return True
    _pid, uid, _gid = struct.unpack("3i", conn.getsockopt(socket.SOL_SOCKET, cred, struct.calcsize("3i")))
    return uid == os.getuid()


# ---------------------------------------------------------------- the client (every `stid` command)


def run_in_server(argv: list[str]) -> int | None:
    """Run the command ``argv`` in a warm server of the same code, and return its exit status;
    None when there is none to run it in (the caller then runs it here)."""
    if os.environ.get("STID_NO_SERVER") or not argv or argv[0] not in SERVED:
        return None
    if any(a in ("-h", "--help", "--version") for a in argv):  # answered at once anyway
        return None
    try:  # a closed stdin, stdout or stderr: its number would be the socket's, sent as the terminal
        for fd in (0, 1, 2):
            os.fstat(fd)
    except OSError:
        return None
    d = _private_dir(socket_dir(), create=False)
    if d is None:
        return None
    path = _socket_in(d)
    if not os.path.exists(path):
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    messages = _Messages(sock)
    started, early = [], []

    def tell(sig: int) -> None:
        try:
            _send_msg(sock, {"signal": int(sig)})
        except OSError:
            pass

    def forward(signum, _frame):
        if not started:  # not taken yet: a Ctrl-C ends the wait here
            early.append(signum)
            raise KeyboardInterrupt
        tell(signum)

    def suspend(_signum, _frame):
        # Ctrl-Z: the command (and its workers) stop, then this process, as a shell expects; fg or
        # bg continues both
        if started:
            tell(signal.SIGSTOP)
        signal.signal(signal.SIGTSTP, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTSTP)
        signal.signal(signal.SIGTSTP, suspend)
        if started:
            tell(signal.SIGCONT)

    old = {s: signal.signal(s, forward) for s in FORWARDED_SIGNALS}
    old[signal.SIGTSTP] = signal.signal(signal.SIGTSTP, suspend)
    try:
        try:
            sock.connect(path)
            umask = os.umask(0o022)
            os.umask(umask)
            _send_msg(sock, {"argv": argv, "cwd": os.getcwd(), "env": dict(os.environ), "umask": umask,
                             "nice": os.getpriority(os.PRIO_PROCESS, 0)}, fds=(0, 1, 2))
        except OSError:  # a server that has gone (a stale socket) or is going: run here
            return None
        sock.settimeout(5.0)
        while True:
            try:
                doc, _ = messages.next()
            except socket.timeout:  # a server that does not take it: say so, and wait on (Ctrl-C ends it)
                print("stid: the warm server (stid serve) has not taken this command in 5 s; waiting (Ctrl-C "
                      "stops; STID_NO_SERVER=1 runs commands without it)", file=sys.stderr, flush=True)
                sock.settimeout(None)
                continue
            if doc is None:
                print("stid: error: the warm server (stid serve) went away before this command's exit status came "
                      "back (what it printed above is all there is); run it again (STID_NO_SERVER=1 runs it "
                      "without the server)", file=sys.stderr)
                return 1
            if "started" in doc:
                started.append(doc["started"])
                sock.settimeout(None)
            if "exit" in doc:
                return int(doc["exit"])
    except KeyboardInterrupt:
        if started or not early:
            raise
        print("interrupted", file=sys.stderr)  # (a server that takes it later sees the connection closed: ended)
        return 130
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        sock.close()


# ---------------------------------------------------------------- the server


def serve(command, idle_s: float = DEFAULT_IDLE_S, out=None) -> int:
    """``stid serve``: load, then run the commands of this user's shells (``command(argv) ->
    exit status``, the stid command's own entry: stid.cli.main_here) until ``idle_s`` without
    one, SIGINT or SIGTERM, or ``stid serve --stop``. Logs one line per command on ``out``
    (default stderr)."""
    from stid.errors import InputError

    out = out or sys.stderr
    d = _private_dir(socket_dir(), create=True)
    if d is None:
        raise InputError(f"{socket_dir()} is not a directory of this user closed to others (mode 700): a server's "
                         "socket there could be reached by others; fix its permissions or set STID_SERVE_DIR")
    path = _socket_in(d)  # before the imports: of the files as they are now
    if len(path.encode()) > 100:
        raise InputError(f"the socket path {path} is too long for a Unix socket; set STID_SERVE_DIR to a short path")
    if _answering(path):
        raise InputError(f"a server for this code is already running ({path}); stop it with `stid serve --stop`")
    t0 = time.monotonic()
    _preload()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    listener.bind(path)
    os.chmod(path, 0o600)
    listener.listen(16)
    stop = []

    def on_stop(signum, _frame):
        stop.append(signum)

    signal.signal(signal.SIGTERM, on_stop)
    signal.signal(signal.SIGINT, on_stop)
    signal.signal(STOP_ASKED, on_stop)  # from the supervisor that read a `stid serve --stop`
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # supervisors are reaped by the kernel
    print(f"stid serve: ready in {time.monotonic() - t0:.1f} s ({path}); `stid` commands of this user and "
          f"environment now start loaded; exits after {idle_s / 60:g} min without one, on Ctrl-C or "
          "`stid serve --stop`", file=out, flush=True)
    last = time.monotonic()
    try:
        while not stop:
            listener.settimeout(max(0.05, min(1.0, last + idle_s - time.monotonic())))
            try:
                conn, _ = listener.accept()
            except (socket.timeout, InterruptedError):
                if time.monotonic() - last >= idle_s:
                    print(f"stid serve: no command for {idle_s / 60:g} min: stopped", file=out, flush=True)
                    break
                continue
            last = time.monotonic()
            _take(conn, out, command, listener)
        if STOP_ASKED in stop:
            print("stid serve: stopped (stid serve --stop)", file=out, flush=True)
        elif stop:
            print("stid serve: stopped", file=out, flush=True)
    finally:
        listener.close()
        try:
            if os.path.exists(path):
                os.unlink(path)
        except OSError:
            pass
    return 0


STOP_ASKED = signal.SIGUSR1  # a supervisor to its server: a `stid serve --stop` came


def stop_server() -> int:
    """``stid serve --stop``: stop this user's servers (of this code, and any left running for
    code since edited or upgraded, which no command can use)."""
    d = _private_dir(socket_dir(), create=False)
    paths = [os.path.join(d, n) for n in sorted(os.listdir(d)) if n.startswith("serve-") and n.endswith(".sock")] \
        if d else []
    stopped = 0
    for path in paths:
        if not _answering(path):
            continue
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(10)
                sock.connect(path)
                _send_msg(sock, {"stop": True})
                _Messages(sock).next()
            stopped += 1
        except OSError:
            pass
    print(f"stid serve: stopped {stopped} server{'s' if stopped != 1 else ''}" if stopped
          else "stid serve: no server is running", file=sys.stderr)
    return 0


def _answering(path: str) -> bool:
    if not os.path.exists(path):
        return False
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        try:
            sock.connect(path)
            return True
        except OSError:
            return False


def _preload() -> None:
    import gc
    import importlib

    for name in PRELOAD:
        importlib.import_module(name)
    from stid.models import recursion

    recursion.load()
    # what the server holds now is never freed: frozen, the runners' garbage collections skip it
    # (and so do not touch, and copy, its memory pages)
    gc.freeze()


def _take(conn: socket.socket, out, command, listener: socket.socket) -> None:
    """Hand a connection to a supervisor forked at once: the request is read there, so a client
    that connects and sends nothing holds up no other command (it did for up to 5 s when the
    server read each request itself)."""
    try:
        if _peer_is_us(conn) and os.fork() == 0:
            try:
                # (a command's processes that held the listening socket kept it answering after the
                # server was gone: every later command waited there for ever)
                listener.close()
                _read_and_supervise(conn, out, command)
            finally:
                os._exit(0)
    except OSError:
        pass
    finally:
        conn.close()


def _read_and_supervise(conn: socket.socket, out, command) -> None:
    fds: list[int] = []
    try:
        conn.settimeout(5)  # a client sends its request at once
        messages = _Messages(conn)
        doc, fds = messages.next(max_fds=3)
        if doc is None:
            return
        if doc.get("stop"):
            server = os.getppid()
            os.kill(server, STOP_ASKED)
            deadline = time.monotonic() + 5
            while os.getppid() == server and time.monotonic() < deadline:  # gone: this one is reparented
                time.sleep(0.02)
            _send_msg(conn, {"exit": 0})  # once the server is gone, so `--stop` returns after it
            return
        if len(fds) != 3 or not isinstance(doc.get("argv"), list):
            return
        conn.settimeout(None)
        print(f"stid serve: {' '.join(doc['argv'])[:160]}", file=out, flush=True)
        _supervise(conn, messages, doc, fds, out, command)
    except (OSError, ValueError):
        return
    finally:
        for fd in fds:
            os.close(fd)


def _supervise(conn: socket.socket, messages: _Messages, doc: dict, fds: list[int], out, command) -> None:
    """Run the command in a runner forked from here; relay signals to it and its status back."""
    import threading

    signal.signal(signal.SIGCHLD, signal.SIG_DFL)  # (the server's SIG_IGN would reap the runner)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        _run(doc, fds, command)  # never returns
    try:  # the runner and its workers in a group of their own, which Ctrl-Z stops as one (also in _run: no race)
        os.setpgid(pid, pid)
    except OSError:
        pass
    for fd in fds:
        os.close(fd)
    fds.clear()
    try:
        _send_msg(conn, {"started": pid})
    except OSError:
        pass

    def relay():
        # the client's signals, and its end: gone without a word, it was killed (kill -9: a signal it can
        # catch it forwards), and its command and workers are killed too, as a cold command's would be (an
        # interrupt made the command print "interrupted" to the terminal after the shell's "Killed")
        while True:
            try:
                msg, _ = messages.next()
            except (OSError, ValueError):
                msg = None
            sig = signal.SIGKILL if msg is None else int(msg.get("signal", signal.SIGINT))
            try:
                if sig in (signal.SIGSTOP, signal.SIGCONT, signal.SIGKILL):  # Ctrl-Z, fg/bg, kill: the workers too
                    os.killpg(pid, sig)
                else:  # the rest to the command, which ends its workers itself
                    os.kill(pid, sig)
            except ProcessLookupError:
                return
            except OSError:
                pass
            if msg is None:
                return

    threading.Thread(target=relay, daemon=True).start()
    _, status = os.waitpid(pid, 0)
    rc = os.waitstatus_to_exitcode(status)
    rc = 128 - rc if rc < 0 else rc  # killed by a signal: as a shell reports it
    print(f"stid serve: {doc['argv'][0]} ended with {rc} after {time.monotonic() - t0:.2f} s", file=out, flush=True)
    try:
        _send_msg(conn, {"exit": rc})
    except OSError:
        pass


def _run(doc: dict, fds: list[int], command) -> None:
    """The runner: become the client's command (its terminal, directory, environment, umask)."""
    rc = 1
    try:
        try:
            os.setpgid(0, 0)
        except OSError:
            pass
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
            os.close(fd)
        enc = sys.stdout.encoding
        sys.stdin = open(0, "r", encoding=enc, closefd=False)
        sys.stdout = open(1, "w", encoding=enc, closefd=False, buffering=1 if os.isatty(1) else -1)
        sys.stderr = open(2, "w", encoding=enc, errors="backslashreplace", closefd=False, buffering=1)
        os.chdir(doc["cwd"])
        os.environ.clear()
        os.environ.update(doc["env"])
        time.tzset()  # (the local time zone is read from TZ at start-up, and now)
        os.umask(int(doc["umask"]))
        try:  # the client's priority (stid live runs its background diagnosis niced below the logger)
            os.setpriority(os.PRIO_PROCESS, 0, int(doc["nice"]))
        except OSError:  # (above the server's own priority needs privileges: then the server's)
            pass
        sys.argv = ["stid", *doc["argv"]]
        try:
            rc = command(doc["argv"]) or 0
        except SystemExit as e:  # argparse's usage errors, --help
            rc = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            if not isinstance(e.code, (int, type(None))):
                print(e.code, file=sys.stderr)
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            rc = 130
        except BaseException:
            import traceback

            traceback.print_exc()
            rc = 1
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(rc)
