"""The ``stid-sim`` command: the simulated car on a pseudo-terminal, or straight to a file."""

from __future__ import annotations

import argparse
import math
import sys

from host.version import installed_version


def build_parser() -> argparse.ArgumentParser:
    from hil_sim import manoeuvres, vehicle  # (here: scipy loads with them, and Ctrl-C then is main's)

    ap = argparse.ArgumentParser(
        prog="stid-sim",
        description="A simulated 1:8 car running the real firmware under MicroPython. Prints "
                    "'port: /dev/pts/N' first, then streams in real time until --duration ends or Ctrl-C. "
                    "With --fast -o RUN.mcap it records faster than real time instead.")
    ap.add_argument("--version", action="version", version=f"%(prog)s {installed_version()}")
    ap.add_argument("--manoeuvre", default="random_steer", choices=manoeuvres.MANOEUVRES)
    ap.add_argument("--effects", default="", help="comma-separated hidden effects: " + ", ".join(vehicle.EFFECT_NAMES))
    ap.add_argument("--car", metavar="FILE", help="another car: a TOML file of its truth (mass, a, b, Iz, Cf, Cr, "
                                                  "...; see hil_sim/car_file.py); default the reference 1:8 car")
    ap.add_argument("--effect-file", action="append", default=[], metavar="FILE",
                    help="hide your own effect: a Python file defining steer_angle, body_loads and/or "
                         "sensor_signals (see hil_sim/effect_file.py; repeatable)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of manoeuvre (plus still and run-up)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--speed", type=float, default=4.0, help="m/s")
    ap.add_argument("--speed-profile", default="constant", choices=manoeuvres.SPEED_PROFILES,
                    help="constant: hold --speed; track: accelerate and brake every 2-5 s within "
                         "+-(--speed-swing) of --speed, as on a track")
    ap.add_argument("--speed-swing", type=float, help="fraction, for --speed-profile track (default 0.25)")
    ap.add_argument("--steer-amp", type=float, default=3.0, help="steer amplitude (rms for random steer), degrees")
    ap.add_argument("--bandwidth", type=float, default=4.0, help="Hz, random steer / chirp")
    ap.add_argument("--still", type=float, default=2.0, help="seconds standing still at the start")
    ap.add_argument("--board", default="pico", choices=["pico", "esp32"])
    ap.add_argument("--rate", type=int, default=500, help="firmware sample rate, Hz")
    ap.add_argument("--batch", type=int, default=10, help="samples per frame")
    ap.add_argument("--start-ticks", type=int, default=0, help="MCU ticks_us at start (near 2^30 tests the wrap)")
    ap.add_argument("--wheel-speeds", action="store_true",
                    help="four hall wheel sensors (fl, fr, rl, rr) instead of one: the firmware sends "
                         "four-wheel frames and --csv gets w_fl,w_fr,w_rl,w_rr [rad/s] from them")
    ap.add_argument("--wheel-ppr", type=int, default=1, help="hall pulses per wheel revolution (magnets)")
    f = ap.add_argument_group("link faults (--ber, --drop-rate, --insert-rate also with --fast)")
    f.add_argument("--ber", type=float, default=0.0, help="bit error rate")
    f.add_argument("--drop-rate", type=float, default=0.0, help="dropped bytes per byte")
    f.add_argument("--insert-rate", type=float, default=0.0, help="inserted garbage per byte")
    f.add_argument("--disconnect-at", type=float, help="unplug the port at this time [s]")
    f.add_argument("--reconnect-after", type=float, default=2.0, help="replug after this many seconds")
    f.add_argument("--link", help="keep a symlink to the current pty here (stable across replug)")
    f.add_argument("--stall", action="append", default=[], metavar="AT:FOR",
                   help="the host stops reading at AT s for FOR s: the car keeps sampling and sends what its "
                        "ring held afterwards; the rest is counted as overruns (repeatable)")
    f.add_argument("--car-fault", type=float, metavar="AT",
                   help="the car's sampler stops at AT s (as after an exception in its timer callback): the "
                        "watchdog restarts the car 2 s later")
    f.add_argument("--fault-log", help=argparse.SUPPRESS)
    o = ap.add_argument_group("faster than real time")
    o.add_argument("--fast", action="store_true", help="record straight to -o instead of serving a port")
    o.add_argument("-o", "--output", help="RUN.mcap for --fast")
    o.add_argument("--overwrite", action="store_true", help="replace -o, --csv, --truth files that exist")
    o.add_argument("--csv", help="also write the CSV import contract here (--fast)")
    o.add_argument("--truth", help="write the truth (parameters, effects) as JSON here (for tests)")
    return ap


def config_from_args(args):
    from hil_sim import manoeuvres, vehicle

    from hil_sim.run import SimConfig

    effects = tuple(e.strip() for e in args.effects.split(",") if e.strip())
    unknown = set(effects) - set(vehicle.EFFECT_NAMES)
    if unknown:
        from difflib import get_close_matches

        near = [m for u in sorted(unknown) for m in get_close_matches(u, vehicle.EFFECT_NAMES, n=1)]
        raise ValueError(f"unknown effect(s) {', '.join(sorted(unknown))}"
                         + (f" (did you mean {', '.join(near)}?)" if near else "")
                         + f"; known: {', '.join(vehicle.EFFECT_NAMES)}")
    _check_options(args)
    stalls = []
    for s in args.stall:
        try:
            at, dur = (float(x) for x in s.split(":"))
        except ValueError:
            raise ValueError(f"--stall takes AT:FOR in seconds, e.g. 5:0.8 (got {s!r})") from None
        if not (0 <= at <= MAX_DURATION_S and 0 < dur <= MAX_DURATION_S):
            raise ValueError(f"--stall {s}: AT from 0 and FOR above 0, each at most {MAX_DURATION_S:g} s")
        stalls.append((at, dur))
    plan = manoeuvres.Plan(name=args.manoeuvre, duration=args.duration, speed=args.speed,
                           steer_amp=math.radians(args.steer_amp), bandwidth=args.bandwidth, still=args.still,
                           speed_profile=args.speed_profile,
                           speed_swing=0.25 if args.speed_swing is None else args.speed_swing)
    _check_outputs(args)
    from hil_sim.effect_file import load_effect_file

    for f in args.effect_file:  # fail here, before any simulation, on a file that cannot work
        load_effect_file(f)
    from hil_sim.car_file import load_car

    car = load_car(args.car) if args.car else vehicle.CarParams()
    return SimConfig(plan=plan, effects=effects, effect_files=tuple(args.effect_file), seed=args.seed, car=car,
                     board=args.board, rate_hz=args.rate, batch=args.batch, start_ticks=args.start_ticks,
                     stalls=tuple(stalls), car_fault_at=args.car_fault,
                     wheel_speeds=args.wheel_speeds, wheel_ppr=args.wheel_ppr)


MAX_DURATION_S = 4 * 3600.0  # s: the manoeuvre is planned whole before it is driven
MAX_SPEED = 30.0  # m/s: the fastest 1:8 cars; the single track is not for more
MAX_STEER_DEG = 30.0  # an RC car's steering lock


def _check_options(args) -> None:
    """Values the simulated car, its link or its firmware cannot take, refused before the run.
    The firmware's limits are its own (firmware/micropython/app.py): on the board it would
    refuse them only once the simulation had started (tests/test_sim_physics.py checks that
    the two agree)."""
    from host import protocol

    def need(ok, text):
        if not ok:
            raise ValueError(text)

    # the manoeuvre is planned whole before it is driven (~45 kB per second of it), so a
    # duration has an end: 4 h is a long track day, and ~0.7 GB
    need(0 < args.duration <= MAX_DURATION_S, f"--duration {args.duration:g}: give more than 0 and at most "
         f"{MAX_DURATION_S:g} s ({MAX_DURATION_S / 3600:g} h); for a longer session record several runs")
    need(0 <= args.still <= MAX_DURATION_S - args.duration,
         f"--still {args.still:g}: give 0 or more seconds, at most {MAX_DURATION_S:g} s with --duration")
    for flag, value in (("--disconnect-at", args.disconnect_at), ("--reconnect-after", args.reconnect_after)):
        need(value is None or 0 <= value <= MAX_DURATION_S,
             f"{flag} {value:g}: give 0 to {MAX_DURATION_S:g} seconds" if value is not None else "")
    need(args.manoeuvre == "standstill" or 1.0 <= args.speed <= MAX_SPEED,
         f"--speed {args.speed:g}: a driving manoeuvre needs 1 to {MAX_SPEED:g} m/s (standing still: "
         "--manoeuvre standstill)")
    need(0 < args.steer_amp <= MAX_STEER_DEG,
         f"--steer-amp {args.steer_amp:g}: give more than 0 and at most {MAX_STEER_DEG:g} degrees")
    need(10 <= args.rate <= 5000 and 1_000_000 % args.rate == 0,
         f"--rate {args.rate}: the firmware samples at 10 to 5000 Hz, a whole number of microseconds apart "
         "(e.g. 200, 500, 1000)")
    need(0 < args.bandwidth < args.rate / 2, f"--bandwidth {args.bandwidth:g}: give a positive frequency below "
         f"half the sample rate ({args.rate / 2:g} Hz)")
    if args.speed_swing is not None:
        need(args.speed_profile == "track", "--speed-swing is for --speed-profile track")
        need(0 <= args.speed_swing < 1, "--speed-swing is a fraction of the speed: 0 to below 1")
    need(args.wheel_ppr >= 1, "--wheel-ppr must be at least 1")
    for flag, rate in (("--ber", args.ber), ("--drop-rate", args.drop_rate), ("--insert-rate", args.insert_rate)):
        need(0 <= rate < 1, f"{flag} {rate:g}: a probability per bit or byte, 0 to below 1")
    most = protocol.max_batch(protocol.VERSION, protocol.SAMPLES4 if args.wheel_speeds else protocol.SAMPLES)
    need(1 <= args.batch <= most, f"--batch {args.batch}: the firmware sends 1 to {most} samples per frame")
    if args.fast:
        for flag, value in (("--disconnect-at", args.disconnect_at), ("--link", args.link)):
            need(value is None, f"{flag} is for the served port; --fast records straight to -o")
    else:
        for flag, value in (("-o", args.output), ("--csv", args.csv)):
            need(value is None, f"{flag} is for --fast; without it stid-sim serves a port for stid-log to record")


def _check_outputs(args) -> None:
    """The files a run will write, checked before it starts: a path that cannot be written
    would otherwise fail after the whole simulation, or leave some of its files written."""
    import os
    from pathlib import Path

    if args.output and Path(args.output).suffix.lower() != ".mcap":
        raise ValueError(f"-o {args.output}: -o writes an MCAP log, give a path ending in .mcap "
                         "(for the CSV import contract use --csv)")
    for flag, path in (("-o", args.output), ("--csv", args.csv), ("--truth", args.truth), ("--link", args.link)):
        if not path:
            continue
        where = Path(path).parent
        if Path(path).is_dir():
            raise ValueError(f"{flag} {path} is a directory: give a file path")
        if flag != "--link" and Path(path).is_file() and not args.overwrite:  # a run is never replaced unasked
            raise ValueError(f"{flag} {path} exists: give another path, or --overwrite to replace it")
        if not where.is_dir():
            raise ValueError(f"{flag} {path}: the directory {where} does not exist; create it or give another path")
        if not os.access(where, os.W_OK):
            raise ValueError(f"{flag} {path}: the directory {where} cannot be written; give another path")


def _quiet_overflow():
    """numpy's overflow warnings off: a car whose motion runs away (an effect file's load of the wrong
    sign) printed a screen of them before the one line that names the file (vehicle._check_bounded)."""
    import numpy as np

    return np.errstate(over="ignore", invalid="ignore")


def main(argv=None) -> int:
    try:  # (Ctrl-C while the simulator loads ends it as Ctrl-C while it runs does, without a traceback)
        ap = build_parser()
        args = ap.parse_args(argv)
    except KeyboardInterrupt:
        return 130
    try:
        cfg = config_from_args(args)
        if args.fast:
            if not args.output:
                ap.error("--fast needs -o RUN.mcap")
            from hil_sim.record import record

            from hil_sim.faults import LinkFaults

            faults = LinkFaults(ber=args.ber, drop_rate=args.drop_rate, insert_rate=args.insert_rate,
                                seed=args.seed)
            with _quiet_overflow():
                stats = record(cfg, args.output, csv_path=args.csv, truth_path=args.truth, faults=faults)
            lossy = args.ber or args.drop_rate or args.insert_rate
            print(f"wrote {args.output}: {stats['samples']} samples"
                  + (f" ({stats['lost_frames']} frames lost, {sum(stats['errors'].values())} rejected, "
                     f"{stats['missing_samples']} samples missing on the faulty link)" if lossy else ""),
                  file=sys.stderr)
            return 0
        from hil_sim.faults import LinkFaults
        from hil_sim.serve import ServeOptions, serve

        opts = ServeOptions(disconnect_at=args.disconnect_at, reconnect_after=args.reconnect_after,
                            link=args.link, fault_log=args.fault_log, truth=args.truth,
                            faults=LinkFaults(ber=args.ber, drop_rate=args.drop_rate,
                                              insert_rate=args.insert_rate, seed=args.seed))
        with _quiet_overflow():
            return serve(cfg, opts)
    except ValueError as e:
        print(f"stid-sim: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # the environment refused something the checks could not foresee (a full disk)
        what = f"cannot write {e.filename}: " if e.filename else ""
        print(f"stid-sim: error: {what}{e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
