"""The ``stid-log`` command: parse arguments, call the logger, print one summary."""

from __future__ import annotations

import argparse
import sys

from host.errors import HostError
from host.live_view import web_port
from host.protocol import LINK_BAUD
from host.version import installed_version


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="stid-log",
        description="Record the car's serial stream into an MCAP file (flushed every second; "
                    "Ctrl-C finishes the file cleanly; an unplugged port is waited for and reopened).")
    ap.add_argument("port", nargs="?", help="serial port, e.g. /dev/ttyUSB0, /dev/ttyACM0 or a "
                                            "/dev/serial/by-id/... link (stable across replug)")
    ap.add_argument("--version", action="version", version=f"%(prog)s {installed_version()}")
    ap.add_argument("-o", "--output", help="output file (default: stid-YYYYmmdd-HHMMSS.mcap, made unique); "
                                           "an existing file is never replaced without --overwrite")
    ap.add_argument("--overwrite", action="store_true", help="replace the -o file if it exists")
    ap.add_argument("--duration", type=float, help="stop after this many seconds")
    ap.add_argument("--baud", type=baud_rate, default=LINK_BAUD,
                    help=f"baud rate: the firmware's UART rate (ignored by USB-CDC; default {LINK_BAUD})")
    ap.add_argument("--idle-timeout", type=float, default=10.0,
                    help="give up if no valid frame arrives within this many seconds (default 10)")
    ap.add_argument("--reconnect-timeout", type=float, default=None,
                    help="after an unplug, wait at most this many seconds for the port (default: forever)")
    ap.add_argument("--hello-from", metavar="EARLIER.mcap|V.toml",
                    help="if no HELLO gets through in this run, take the configuration from this earlier log of "
                         "the same board, or from the [board] table a vehicle file declares "
                         "(docs/hello_in_vehicle_file.md); the file says so")
    ap.add_argument("--repair", metavar="FILE", help="rewrite a cut-short MCAP file into a complete one, then exit")
    ap.add_argument("--repair-output", metavar="OUT", help="where --repair writes (default FILE.repaired.mcap)")
    ap.add_argument("--status", action=argparse.BooleanOptionalAction, default=None,
                    help="live status line (default: only on a terminal)")
    lv = ap.add_argument_group("identify while driving (stid live, in a process of its own: it never costs a sample)")
    lv.add_argument("--live", action="store_true",
                    help="every few seconds: each parameter's value and 95%% precision, what the data still lack, "
                         "'done' when every target is reached, the diagnosis once the data carry it")
    lv.add_argument("--vehicle", metavar="V.toml", help="the car's vehicle file (needed by --live)")
    lv.add_argument("--model", default="bicycle", help="the model to identify live (default bicycle)")
    lv.add_argument("--target", action="append", metavar="NAME=PCT",
                    help="e.g. Iz=3%%: the precision to reach (default: the vehicle file's [targets], else 5%%)")
    lv.add_argument("--web", type=web_port, nargs="?", const=0, metavar="PORT",
                    help="also serve the live view on http://127.0.0.1:PORT/ (no PORT: a free one, printed)")
    lv.add_argument("--every", type=float, default=2.0, help="seconds between live updates (default 2)")
    return ap


# A UART's rates: from the slowest standard one to what USB-serial bridges reach (FTDI's FT232H
# 12 Mbaud). 0 is no rate (on a real line it means hang up); beyond, the OS refuses it with a traceback.
BAUD_RANGE = (50, 12_000_000)


def baud_rate(text: str) -> int:
    """--baud's value: a whole number of bits per second within BAUD_RANGE (argparse then says what is wrong)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of bits per second") from None
    lo, hi = BAUD_RANGE
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"{value} is no UART rate: give {lo} to {hi:,} bits per second (the "
                                         f"firmware's is {LINK_BAUD}; USB-CDC boards ignore it)")
    return value


def live_arguments(args, ap) -> list | None:
    """The live view's command-line arguments, or None without --live (its options alone are refused)."""
    if not args.live:
        given = [o for o, v in (("--vehicle", args.vehicle), ("--target", args.target), ("--web", args.web))
                 if v is not None]
        if given:
            ap.error(f"{', '.join(given)} {'belongs' if len(given) == 1 else 'belong'} to --live: add --live")
        return None
    if not args.vehicle:
        ap.error("--live needs the car's vehicle file: --vehicle V.toml (mass, a, b; see docs/examples/rc8.toml)")
    out = ["--vehicle", args.vehicle, "--model", args.model, "--every", str(args.every)]
    for t in args.target or []:
        out += ["--target", t]
    if args.web is not None:
        out += ["--web", str(args.web)]
    return out


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        if args.repair:
            from host.repair import repair_cli

            return repair_cli(args.repair, args.repair_output, args.hello_from)
        if not args.port:
            ap.error("give the serial port, e.g. stid-log /dev/ttyUSB0 (or --repair FILE)")
        for flag, value in (("--duration", args.duration), ("--idle-timeout", args.idle_timeout),
                            ("--reconnect-timeout", args.reconnect_timeout)):
            # inf is a fair "no end" (no option is also); nan or a negative time is a typo
            if value is not None and not value > 0:
                ap.error(f"{flag} {value:g}: give a positive number of seconds")
        live = live_arguments(args, ap)
        if live is not None:  # a vehicle file the view cannot read is refused now, not after the run
            check_live(live)
        if args.hello_from:  # refused now, not after the run it was meant to rescue
            from host.hello_supply import check_source

            check_source(args.hello_from)
        from host.logger import LogOptions, Logger, summary_line

        stats = Logger(LogOptions(port=args.port, output=args.output, duration=args.duration, baud=args.baud,
                                  idle_timeout=args.idle_timeout, reconnect_timeout=args.reconnect_timeout,
                                  status=args.status, hello_from=args.hello_from,
                                  overwrite=args.overwrite, live=live)).run()
        print(summary_line(stats), file=sys.stderr)
        return 0
    except HostError as e:
        print(f"stid-log: error: {e}", file=sys.stderr)
        return e.exit_code
    except OSError as e:  # the environment refused something (permissions, devices)
        where = f": {e.filename}" if e.filename else ""
        print(f"stid-log: error: {e.strerror or e}{where}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


def check_live(argv: list) -> None:
    """The live view's arguments checked by the view itself (vehicle file, model, targets),
    before the port is opened: a mistake there is said at once, not after the run."""
    import subprocess

    proc = subprocess.run([sys.executable, "-m", "stid.cli", "live", "--check", "-", *argv],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise HostError((proc.stderr.strip().splitlines() or ["the live view refused its arguments"])[-1]
                        .replace("stid live: error: ", "--live: "))


if __name__ == "__main__":
    sys.exit(main())
