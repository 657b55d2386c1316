"""The ``stid-log`` command: parse arguments, call the logger, print one summary."""

from __future__ import annotations

import argparse
import sys

from host.errors import HostError
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
    ap.add_argument("--baud", type=int, default=LINK_BAUD,
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
    return ap


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
        if args.hello_from:  # refused now, not after the run it was meant to rescue
            from host.hello_supply import check_source

            check_source(args.hello_from)
        from host.logger import LogOptions, Logger, summary_line

        stats = Logger(LogOptions(port=args.port, output=args.output, duration=args.duration, baud=args.baud,
                                  idle_timeout=args.idle_timeout, reconnect_timeout=args.reconnect_timeout,
                                  status=args.status, hello_from=args.hello_from,
                                  overwrite=args.overwrite)).run()
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


if __name__ == "__main__":
    sys.exit(main())
