"""Bytes in, MCAP out: decode, unwrap MCU time, fit the clock, keep statistics.

Used by ``stid-log`` on a serial port and by the simulator's fast mode on the
firmware's byte stream, so both produce the same files.

Besides the exact frames, every sample goes to ``/stid/samples`` as one JSON
message in SI units at its own instant on the host clock (the clock model), which
is what a viewer such as Foxglove plots. Converting needs the HELLO: samples that
arrive before the first HELLO wait for it (at most ``PENDING_MAX`` of them), so a
HELLO lost on the link costs the viewer nothing once any later one gets through.
"""

from __future__ import annotations

import numpy as np

from host import protocol as p
from host.clock import ClockModel, TickUnwrapper
from host.frame_decoder import FrameDecoder
from host.mcap_log import McapLog
from host.si_view import SiView

UNKNOWN_BOOT = "?"
PENDING_MAX = 60_000  # samples held for the SI view while no HELLO has come (a minute at 1 kHz)


class _Boot:
    def __init__(self, boot_id: str):
        self.id = boot_id
        self.ticks = TickUnwrapper()
        self.clock = ClockModel()
        self.last_index: int | None = None
        self.hello: dict | None = None
        self.fit: dict | None = None
        self.frames = 0
        self.overruns = 0
        self.missed = 0  # timer periods the firmware could not sample (protocol 3 STATUS)
        self.si: SiView | None = None  # the SI converter, once this boot's HELLO is known
        self.t0_us: int | None = None  # first sample's MCU time: the SI view's t = 0
        self.first_ns: int | None = None  # host times of the boot's first and last samples
        self.last_log_ns: int | None = None  # the last sample's log time (they never run back)
        self.last_ns: int | None = None

    def clock_fit(self) -> dict:
        # refitting is a least-squares solve: do it every 50 frames, not every frame
        self.frames += 1
        if self.fit is None or self.frames % 50 == 0:
            self.fit = self.clock.fit()
        return self.fit


class Recorder:
    """Feed it what the port delivered; it writes everything to ``log``."""

    def __init__(self, log: McapLog):
        self.log = log
        self.decoder = FrameDecoder()
        self.boot = _Boot(UNKNOWN_BOOT)
        self.boots: list[_Boot] = [self.boot]
        self.hello: dict = {}
        self.samples = 0
        self.missing_samples = 0  # gaps in the sample index: lost frames or car-side overruns
        self.last_status: dict | None = None
        self.latest = {"ay": float("nan"), "r": float("nan")}
        self.gaps: list[dict] = []
        self.uids: list[str] = []  # board uids seen in HELLOs, in order
        self._pending: list = []  # (boot, raw samples, t_mcu, log_ns) waiting for a HELLO
        self._pending_n = 0
        self.supplied_hello: dict | None = None
        self.last_host_ns: int | None = None  # a HELLO from elsewhere, used only if none arrives

    @property
    def stats(self):
        return self.decoder.stats

    def feed(self, data: bytes, host_ns: int) -> None:
        """Everything one read of the port delivered, received at ``host_ns``.

        Work is done per read, not per frame: consecutive SAMPLES frames are
        decoded and unwrapped together, and the frames and samples channels get
        one message per read. That is what keeps up with USB line rate.
        """
        if not data:
            return
        self.last_host_ns = host_ns
        self.log.raw(data, host_ns)
        frames = self.decoder.feed(data)
        if not frames:
            return
        self.log.frames([f.payload for f in frames], host_ns)
        group = []
        for fr in frames:
            if fr.type in p.SAMPLE_TYPES:
                group.append(fr)
                continue
            if group:
                self._samples(group, host_ns)
                group = []
            self._other(fr, host_ns)
        if group:
            self._samples(group, host_ns)

    def _new_boot(self, boot_id: str, host_ns: int, reason: str) -> None:
        if self.boot.id.startswith(UNKNOWN_BOOT) and self.boot.hello is None and reason == "hello":
            # the first HELLO names the boot we were already in (samples may have come first,
            # or a restart was seen in the sample index before its HELLO arrived)
            self.boot.id = boot_id
            return
        self.boot = _Boot(boot_id)
        self.boots.append(self.boot)
        self.event("boot", host_ns, f"firmware boot {boot_id} ({reason})")

    def _other(self, fr, host_ns: int) -> None:
        if fr.type == p.HELLO:
            try:
                doc = fr.hello()
            except (ValueError, UnicodeDecodeError, KeyError, TypeError):  # passed the CRC, yet unreadable
                self.stats.errors["hello"] += 1
                return
            bid = str(doc.get("boot_id", UNKNOWN_BOOT))
            if bid != self.boot.id:
                self._new_boot(bid, host_ns, "hello")
            uid = doc.get("uid")
            if uid and uid not in self.uids:
                self.uids.append(uid)
            first = self.boot.hello is None
            if first:
                self.boot.hello = doc
                self.boot.si = SiView(doc)
                self.log.metadata("stid.hello", {**doc, "boot_id": bid})
            self.hello = doc
            self.log.json("hello", doc, host_ns)
            if first:
                self._release_pending()
        elif fr.type == p.STATUS:
            st = fr.status()
            self.last_status = st
            self.boot.overruns = st["overruns"]  # the firmware's own count since boot
            if st.get("missed") is not None:
                self.boot.missed = st["missed"]  # index advanced, no sample: a gap the car knows of
            self.log.json("status", {**st, "boot": self.boot.id, "seq": fr.seq}, host_ns)

    def _samples(self, frames, host_ns: int) -> None:
        first = [f.samples_index() for f in frames]
        counts = [f.samples_count() for f in frames]
        b = self.boot
        # split the group where the sample index runs backwards (a restart without HELLO yet)
        prev = b.last_index
        for k, (i0, n) in enumerate(zip(first, counts)):
            if prev is not None and (i0 - prev - 1) % p.MOD > p.MOD // 2:
                if k:
                    self._samples(frames[:k], host_ns)
                self._new_boot(f"{UNKNOWN_BOOT}{len(self.boots)}", host_ns, "sample index restarted")
                self._samples(frames[k:], host_ns)
                return
            if prev is not None:
                self.missing_samples += (i0 - prev - 1) % p.MOD
            prev = (i0 + n - 1) % p.MOD
        arr = p.samples_from_records((f.version, f.type, f.samples_bytes()) for f in frames)
        host_us = host_ns / 1000.0
        t_mcu = b.ticks.unwrap_array(arr["t_us"], host_us)
        # the last sample was taken before the frame was sent: its host time is an upper bound
        b.clock.add(float(t_mcu[-1]), host_us)
        b.last_index = prev
        if b.first_ns is None:
            b.first_ns = host_ns
        b.last_ns = host_ns
        self.samples += len(arr)
        fit = b.clock_fit()
        log_ns = np.minimum((b.clock.to_host_us(t_mcu, fit) * 1000).astype(np.int64), host_ns)
        # never back in time: a refit of the clock (every 50 frames, and from few points at the
        # start) can move its offset back by milliseconds; the samples then share an instant
        # until theirs catch up
        if b.last_log_ns is not None:
            log_ns = np.maximum(log_ns, b.last_log_ns)
        log_ns = np.maximum.accumulate(log_ns)
        b.last_log_ns = int(log_ns[-1])
        index = (np.repeat(np.asarray(first, dtype=np.int64), counts)
                 + np.arange(len(arr)) - np.repeat(np.cumsum([0] + counts[:-1]), counts)) % p.MOD
        if b.t0_us is None:
            b.t0_us = int(t_mcu[0])
        if b.si is not None:
            self._write_si(b, arr, index, t_mcu, log_ns)
        elif self._pending_n < PENDING_MAX:
            self._pending.append((b, arr, index, t_mcu, log_ns))
            self._pending_n += len(arr)

    def _write_si(self, b: _Boot, arr, index, t_mcu, log_ns) -> None:
        lines = b.si.lines(b.id, arr, index, t_mcu, b.t0_us)
        self.log.sample_messages(lines, log_ns.tolist())
        self.latest["ay"], self.latest["r"] = b.si.latest

    def _release_pending(self) -> None:
        """Samples that came before their boot's HELLO, now that it is known."""
        keep = []
        for item in self._pending:
            if item[0].si is not None:
                self._write_si(*item)
            else:
                keep.append(item)
        self._pending = keep
        self._pending_n = sum(len(it[1]) for it in keep)

    def supply_hello(self, doc: dict, source: str) -> None:
        """A HELLO from elsewhere (an earlier log of the same board, a vehicle file) for a
        run in which none arrived: written as such, with where it came from."""
        doc = {**doc, "supplied_from": source}
        self.supplied_hello = doc
        for b in self.boots:
            if b.hello is None:
                b.hello = doc
                b.si = SiView(doc)
        self.hello = doc
        self.log.metadata("stid.hello", {**doc, "boot_id": self.boot.id})
        self.log.json("hello", doc, self.last_host_ns or 0)
        self._release_pending()

    @property
    def hello_seen(self) -> bool:
        return any(b.hello is not None and "supplied_from" not in b.hello for b in self.boots)

    def event(self, name: str, host_ns: int, detail: str = "") -> None:
        self.log.json("events", {"event": name, "detail": detail, "boot": self.boot.id}, host_ns)

    def car_restarts(self) -> list[dict]:
        """Each boot after the first: the car restarted (watchdog, brown-out, reset button).
        Its reset cause (from its HELLO, when one came) and the seconds without samples."""
        out = []
        for before, b in zip(self.boots, self.boots[1:]):
            cause = b.hello.get("reset_cause") if b.hello and "supplied_from" not in b.hello else None
            gap = ((b.first_ns - before.last_ns) / 1e9 if b.first_ns is not None and before.last_ns is not None
                   else None)
            out.append({"boot": b.id, "reset_cause": cause, "gap_s": gap})
        return out

    def stats_doc(self) -> dict:
        d = self.stats.as_dict()
        d.update({"samples": self.samples, "missing_samples": self.missing_samples,
                  "mcu_overruns": sum(b.overruns for b in self.boots),
                  "mcu_missed": sum(b.missed for b in self.boots), "gaps": self.gaps,
                  "car_restarts": self.car_restarts(), "hello_seen": self.hello_seen})
        return d

    def write_stats(self, host_ns: int) -> None:
        self.log.json("stats", self.stats_doc(), host_ns)

    def finish(self, host_ns: int) -> dict:
        self._pending.clear()  # no HELLO came: their frames are in /stid/frames, the SI view cannot be
        stats = self.stats_doc()
        self.log.json("stats", stats, host_ns)
        self.log.metadata("stid.stats", stats)
        self.log.metadata("stid.clock", {b.id: b.clock.fit() for b in self.boots if b.clock._bins})
        return stats
