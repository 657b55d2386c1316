"""Say loudly, while logging, when nothing useful is being recorded.

The logger asks ``LinkWatch.check`` about once a second. It compares the decoder's
counts with the last check and returns warnings (one line each, for the terminal)
with an event name (for ``/stid/events``). Each condition warns when it starts and
again at most every ``REPEAT_S`` while it lasts, so a bad run is loud without a
flood.

Thresholds and why:
- rejects: more than ``REJECT_SHARE`` of the frames in a check interval fail a
  check. A sound link rejects none; a few percent is a noisy but usable link (the
  fit leaves the lost samples out); beyond 10% the data thins out quickly and the
  cause (baud rate, cable, another program on the port) wants fixing now.
- a newer protocol version: warned at the first frame; nothing of it can be used.
- silence: no valid frame for ``SILENCE_S`` while the port stays open. The car
  sends samples continuously (and STATUS every second), so 3 s of nothing means the
  board stopped, not a pause. A quiet port is not an unplug: it is no gap in the
  file, only this warning and event.
- no HELLO: samples for ``NO_HELLO_S`` but no HELLO (the firmware sends one every
  1-2 s): the file holds counts whose scale nobody knows.
"""

from __future__ import annotations

REJECT_SHARE = 0.10
SILENCE_S = 3.0
NO_HELLO_S = 5.0
REPEAT_S = 10.0

# what each reject reason (host.protocol.ERROR_KINDS) means to a user
REASONS = {
    "crc": "damaged in transit (CRC)",
    "cobs": "broken framing",
    "short": "too short",
    "too_long": "too long (no frame delimiter)",
    "version": "not a stid protocol version",
    "version_newer": "a newer protocol version than this stid knows",
    "type": "of an unknown type",
    "length": "of the wrong length for their type",
    "hello": "HELLO that does not decode",
}


def describe_rejects(errors: dict, limit: int = 3) -> str:
    """'12 damaged in transit (CRC), 3 broken framing' for the largest counts."""
    items = sorted(((n, k) for k, n in errors.items() if n), reverse=True)[:limit]
    return ", ".join(f"{n} {REASONS.get(k, k)}" for n, k in items)


def advice(errors: dict) -> str:
    """What to do about the rejects that dominate."""
    if errors.get("version_newer"):
        return "the board's firmware is newer than this stid: this log needs a newer stid (pip install -U stid)"
    bad = sum(errors.values())
    framing = sum(errors.get(k, 0) for k in ("crc", "cobs", "short", "too_long"))
    if bad and framing >= 0.5 * bad:
        return "check the baud rate (--baud), the cable, and that no other program reads the port"
    return "firmware and host disagree on the protocol: flash the firmware that matches this stid (stid flash)"


class LinkWatch:
    def __init__(self, now: float):
        self._last = (0, {})
        self._last_frame_t = now
        self._last_accepted = 0
        self._warned: dict[str, float] = {}
        self._first_sample_t: float | None = None

    def _due(self, key: str, now: float) -> bool:
        t = self._warned.get(key)
        if t is None or now - t >= REPEAT_S:
            self._warned[key] = now
            return True
        return False

    def clear(self, key: str) -> None:
        self._warned.pop(key, None)

    def check(self, now: float, stats, samples: int, hello_seen: bool, connected: bool) -> list[tuple[str, str]]:
        """[(event, one-line warning)] for what went wrong since the last check."""
        out = []
        accepted, errors = stats.accepted, dict(stats.errors)
        prev_acc, prev_err = self._last
        d_acc = accepted - prev_acc
        d_err = {k: n - prev_err.get(k, 0) for k, n in errors.items()}
        d_bad = sum(d_err.values())
        self._last = (accepted, errors)
        if d_err.get("version_newer") and self._due("version_newer", now):
            out.append(("rejects", f"{d_err['version_newer']} frames of a newer protocol version were rejected: "
                                   + advice({"version_newer": 1})))
        elif d_bad and d_bad > REJECT_SHARE * (d_acc + d_bad) and self._due("rejects", now):
            share = 100.0 * d_bad / (d_acc + d_bad)
            out.append(("rejects", f"{share:.0f}% of frames rejected in the last second ({describe_rejects(d_err)}): "
                                   + advice(d_err)))
        if d_acc:
            self._last_frame_t = now
            self.clear("silence")
        elif connected and accepted and now - self._last_frame_t >= SILENCE_S and self._due("silence", now):
            out.append(("silence", f"no valid frame for {now - self._last_frame_t:.0f} s although the port is open: "
                                   "is the car powered and its firmware running? (logging continues)"))
        if samples and self._first_sample_t is None:
            self._first_sample_t = now
        if (not hello_seen and self._first_sample_t is not None and now - self._first_sample_t >= NO_HELLO_S
                and self._due("no_hello", now)):
            why = describe_rejects({k: errors[k] for k in ("hello", "crc", "cobs") if errors.get(k)})
            out.append(("no_hello", f"samples for {now - self._first_sample_t:.0f} s but no HELLO got through "
                                    f"(rejected: {why or 'none'}): without it the file has no ADC scale"))
        return out
