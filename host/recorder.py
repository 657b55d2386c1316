"""Bytes in, MCAP out: decode, unwrap MCU time, fit the clock, keep statistics.

Used by ``stid-log`` on a serial port and by the simulator's fast mode on the
firmware's byte stream, so both produce the same files.
"""

from __future__ import annotations

import numpy as np

from host import protocol as p
from host import units
from host.clock import ClockModel, TickUnwrapper
from host.frame_decoder import FrameDecoder
from host.mcap_log import McapLog

UNKNOWN_BOOT = "?"


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
        if self.boot.id == UNKNOWN_BOOT and reason == "hello":
            # the first HELLO names the boot we were already in (samples may have come first)
            self.boot.id = boot_id
            return
        self.boot = _Boot(boot_id)
        self.boots.append(self.boot)
        self.event("boot", host_ns, f"firmware boot {boot_id} ({reason})")

    def _other(self, fr, host_ns: int) -> None:
        if fr.type == p.HELLO:
            doc = fr.hello()
            bid = str(doc.get("boot_id", UNKNOWN_BOOT))
            if bid != self.boot.id:
                self._new_boot(bid, host_ns, "hello")
            if self.boot.hello is None:
                self.boot.hello = doc
                self.log.metadata("stid.hello", {**doc, "boot_id": bid})
            self.hello = doc
            self.log.json("hello", doc, host_ns)
        elif fr.type == p.STATUS:
            st = fr.status()
            self.last_status = st
            self.boot.overruns = st["overruns"]  # the firmware's own count since boot
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
        self.samples += len(arr)
        fit = b.clock_fit()
        log_ns = np.minimum((b.clock.to_host_us(t_mcu, fit) * 1000).astype(np.int64), host_ns)
        index = (np.repeat(np.asarray(first, dtype=np.int64), counts)
                 + np.arange(len(arr)) - np.repeat(np.cumsum([0] + counts[:-1]), counts)) % p.MOD
        doc = {"boot": b.id, "n": len(arr), "index": index.tolist(), "t_mcu_us": t_mcu.tolist(),
               "t_host_ns": log_ns.tolist()}
        four = any(f.type == p.SAMPLES4 for f in frames)
        for name in p.SAMPLE_FIELDS[1:]:
            if four or not name.startswith("wheel") or name in ("wheel_count", "wheel_t_us"):
                doc[name] = arr[name].tolist()
        self.log.json("samples", doc, int(log_ns[0]))
        if self.hello:
            self.latest["ay"] = float(units.accel_si(arr["ay"][-1:], self.hello)[0])
            self.latest["r"] = float(units.yaw_rate_si(arr["yaw"][-1:], self.hello)[0])

    def event(self, name: str, host_ns: int, detail: str = "") -> None:
        self.log.json("events", {"event": name, "detail": detail, "boot": self.boot.id}, host_ns)

    def stats_doc(self) -> dict:
        d = self.stats.as_dict()
        d.update({"samples": self.samples, "missing_samples": self.missing_samples,
                  "mcu_overruns": sum(b.overruns for b in self.boots), "gaps": self.gaps})
        return d

    def write_stats(self, host_ns: int) -> None:
        self.log.json("stats", self.stats_doc(), host_ns)

    def finish(self, host_ns: int) -> dict:
        stats = self.stats_doc()
        self.log.json("stats", stats, host_ns)
        self.log.metadata("stid.stats", stats)
        self.log.metadata("stid.clock", {b.id: b.clock.fit() for b in self.boots if b.clock._bins})
        return stats
