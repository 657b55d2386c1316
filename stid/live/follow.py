"""``stid live RUN``: the loop that reads the growing file, updates, and shows.

Every ``every`` seconds the newest state of the file is read and fitted. An update that
takes longer than that is followed at once by one on the newest data: the view skips
ahead, it never works through a backlog. A file that does not change is not fitted
again; what the view says about it (a quiet port) still is.

Started by ``stid-log --live`` (``from_logger``), the logger's own lines come on stdin
and are shown above the table; stdin closing means the logger has finished the file:
one last update on the finished file, then the view ends.
"""

from __future__ import annotations

import json
import queue
import signal
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

from stid.live import lacks
from stid.live.diagnosis import MIN_DRIVING_S, BackgroundDiagnosis
from stid.live.estimator import Estimator, done_line
from stid.live.source import Source
from stid.live.terminal import TerminalView

LAST_WAIT_S = 20.0  # after the logger ends: how long to wait for its file to be finished


def live(path, vehicle, model: str, targets: dict, targets_from: str, follow: bool = False, every: float = 2.0,
         web_port: int | None = None, json_lines: bool = False, from_logger: bool = False,
         diagnose: bool = True, stream=None) -> int:
    stream = stream or sys.stdout
    est = Estimator(vehicle, model, targets, targets_from)
    src = Source(path, vehicle)
    view = None if json_lines else TerminalView(stream)
    msgs: queue.Queue = queue.Queue()
    logger_done = threading.Event()
    if from_logger:
        threading.Thread(target=_read_messages, args=(sys.stdin, msgs, logger_done), daemon=True).start()
    stop = threading.Event()
    old = {}
    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            old[s] = signal.signal(s, lambda *_: stop.set())
    server = None
    diag = BackgroundDiagnosis(path, vehicle.path, model) if diagnose else None
    name = Path(path).name
    try:
        if web_port is not None:
            from stid.live.web import LiveServer

            server = LiveServer(web_port)
            _say(view, f"stid live: the live view is at {server.url} (this machine only)", json_lines)
        last = None
        shown = None
        logger_ended_at = None
        while True:
            t0 = time.monotonic()
            snap = src.poll()
            if last is None or snap.changed:
                up = est.update(snap, name)
            else:  # nothing new to fit: only what the view says about the data may have changed
                up = replace(last, state=list(snap.state), wall=time.time())
                up.done = done_line(up)
            if diag is not None:  # (an update that is the view's only one waits for its diagnosis)
                up.diagnosis = diag.poll(up.driving_s, snap.finished, wait=not follow or (last is None and snap.finished))
                if diag.effect and up.params:
                    with_named_effect(up, model, diag.effect)
                elif diag.unexplained and up.params:
                    with_unexplained_error(up, model)
                elif up.done and diag.text is None:
                    before_the_diagnosis(up)
            said = (up.seq, tuple(up.state), up.diagnosis, tuple(up.lacking), up.done)
            if said != shown:  # (an unchanged file and nothing new to say: nothing is shown again)
                _show(view, server, up, json_lines, stream)
                shown = said
            last = up
            while not msgs.empty():
                _say(view, msgs.get(), json_lines)
            if not follow or stop.is_set():
                break
            if snap.finished and (not from_logger or logger_done.is_set()):
                break
            pace = every
            if logger_done.is_set() and not Path(path).exists():
                # (a logger that got no data leaves no file: its own error says why, at once; the view had
                # redrawn 'waiting for it to appear' for 20 s before it, ~100 times)
                break
            if logger_done.is_set():  # the logger has ended: its file is finished any moment now
                logger_ended_at = logger_ended_at or time.monotonic()
                if time.monotonic() - logger_ended_at > LAST_WAIT_S:
                    break
                pace = min(every, 0.2)
            # wait for the next tick, showing the logger's lines as they come
            while not stop.is_set():
                left = pace - (time.monotonic() - t0)
                if left <= 0:
                    break
                try:
                    _say(view, msgs.get(timeout=min(left, 0.25)), json_lines)
                except queue.Empty:
                    pass
            if stop.is_set():
                break
        if server is not None and not from_logger and not stop.is_set():
            # (the page is what was asked for: it had closed with the view's one update on a finished file)
            _say(view, f"stid live: no more updates ({name} is {'finished' if last.finished else 'as it was'}); "
                       f"the page stays at {server.url} until Ctrl-C", json_lines)
            while not stop.wait(0.5):
                pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if diag is not None:
            diag.stop()
        if server is not None:
            server.close()
    return 0


def with_named_effect(up, model: str, effect: str) -> None:
    """The diagnosis names an effect the watched model lacks: its residual is model error, which
    more driving does not shrink as the plan assumes, and its intervals hold only if the model
    were right, so a reached target is not the answer: no "done", and what to add instead."""
    _instead_of_done(up, f"a model with what the diagnosis names: --model {model}+{effect} (the fit then misses "
                         f"less; without {effect} a reached target is not the answer: the intervals hold only if "
                         "the model were right)", model_rejected=True)


def with_unexplained_error(up, model: str) -> None:
    """The diagnosis finds {model} short of its noise floor and names nothing: as with a named
    effect, more driving does not make its intervals the answer."""
    _instead_of_done(up, f"what {model} misses (the diagnosis finds an error no catalogue effect explains: "
                         "stid diagnose on the file, then --model with it or an effect file of your own); "
                         "until then a reached target is not the answer", model_rejected=True)


def before_the_diagnosis(up) -> None:
    """Targets reached before the diagnosis has answered: whether the model lacks an effect
    decides whether they are the answer (a model missing a servo lag reaches tight intervals
    around the wrong values), so no "done" yet."""
    _instead_of_done(up, f"the diagnosis (once {MIN_DRIVING_S:.0f} s of driving are recorded): the targets are "
                         "reached, but only a model that lacks nothing the data show makes them the answer")


def _instead_of_done(up, line: str, model_rejected: bool = False) -> None:
    """No "done"; ``line`` first of what is lacking, once however often the view updates.
    ``model_rejected``: the data reject the watched model, so the plan's "drive N min more for
    Iz" lines, worked out as if it were right, go (they swung from update to update on the
    model's error); what the data lack whatever the model (a stand-still) stays."""
    up.done = None
    if model_rejected:
        up.lacking = [x for x in up.lacking if x in lacks.FACTS_OF_THE_DATA]
    if line not in up.lacking:
        up.lacking = [line] + up.lacking


def _read_messages(stdin, msgs: queue.Queue, done: threading.Event) -> None:
    try:
        for line in stdin:
            line = line.rstrip("\n")
            if line:
                msgs.put(line)
    except (OSError, ValueError):
        pass
    done.set()


def _say(view, text: str, json_lines: bool) -> None:
    if view is not None:
        view.message(text)
    else:
        print(text, file=sys.stderr, flush=True)


def _show(view, server, up, json_lines: bool, stream) -> None:
    doc = None
    if server is not None or json_lines:
        doc = up.to_json()  # (every number in it is finite or null)
    if server is not None:
        server.publish(doc)
    if json_lines:
        stream.write(json.dumps(doc, allow_nan=False) + "\n")
        stream.flush()
    else:
        view.show(up)
