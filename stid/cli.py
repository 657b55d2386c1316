"""The ``stid`` command. Each subcommand parses its arguments and calls a plain
function (which the tests call directly); user errors end in one line on stderr
and a non-zero exit, never a traceback."""

from __future__ import annotations

import argparse
import gc
import sys
from pathlib import Path

from host.errors import HostError
from host.live_view import web_port
from stid.errors import StidError

RUNS_HELP = ("RUN.mcap (stid-log), RUN.csv (import contract, or mapped by [csv]), a ROS 2 bag (directory or .mcap), "
             "a ROS 1 .bag, or a directory of per-topic CSVs (docs/ros.md)")


def _json(doc) -> str:
    """JSON as every parser reads it: a value that is not a number (a noise floor the data are
    too short for) is null, not NaN."""
    import json
    import math

    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(doc), indent=1, allow_nan=False, default=float)


def _cmd_flash(args) -> int:
    from stid.flash import flash

    return flash(args.board, port=args.port, dry_run=args.dry_run, rate_hz=args.rate, batch=args.batch,
                 wheels=args.wheels, build_dir=args.build_dir)


def _cmd_export(args) -> int:
    from stid.export import export_csv

    return export_csv(args.run, args.csv, args.vehicle, overwrite=args.overwrite)


def _cmd_fit(args) -> int:
    from stid.analysis.noise_floor import submit_floor
    from stid.fit.fitting import fit
    from stid.progress import Progress
    from stid.workers import worker_pool

    vehicle, runs = _vehicle_and_runs(args)
    held = _validation_runs(args, vehicle, runs)
    judged_on = _judged_stretches(held if held else runs, bool(held))
    # the noise floor needs only the data: it is estimated on the other core while the model is fitted
    with Progress(f"fitting {args.model} ({args.method})") as prog, worker_pool(1) as pool:
        floor = submit_floor(pool, judged_on) if pool and judged_on is not None else None
        res = fit(runs, vehicle, args.model, args.method)
        prog.step("the noise floor")
        judged, floor, floor_se = _judge(res, args.model, vehicle, judged_on, held, floor)
    import math

    from stid.analysis.noise_floor import above_floor, below_floor, below_floor_small, floor_words, \
        gyro_zero_points

    # (a solver that stopped short is said so, below_floor's words: not a small effect)
    small = below_floor_small(judged, floor, floor_se, gyro_zero_points(judged, judged_on)) if res.converged else {}
    if args.json:
        doc = res.to_json()
        if held:
            doc["validation"] = {"runs": [r.name for r in held], "fit": {k: round(v, 2) for k, v in judged.fit.items()}}
        doc["noise_floor"] = {k: round(v, 2) for k, v in floor.items()}
        doc["noise_floor_stderr"] = {k: round(v, 3) for k, v in floor_se.items()}
        # (fit points short of the floor: when not empty, the intervals assume a model that is not right)
        doc["below_floor"] = below_floor(judged, floor, floor_se)
        doc["below_floor_small"] = small  # (beyond chance, under below_floor's 2 points)
        doc["above_floor"] = above_floor(judged.fit, floor, floor_se)
        if doc["below_floor"]:  # (a script that reads the warnings hears it too)
            doc.setdefault("warnings", []).append(_below_floor_words(doc["below_floor"], res.converged, args))
        if small:
            doc.setdefault("notes", []).append(_small_gap_words(small, args))
        if not all(math.isfinite(v) for v in floor.values()):  # (why there is none, as the text says)
            doc.setdefault("notes", []).append(floor_words({o: v for o, v in floor.items() if not math.isfinite(v)},
                                                           floor_se))
        print(_json(doc))
    else:
        print(res.table())
        if held:
            print(f"  judged on {', '.join(r.name for r in held)} (not fitted to): "
                  + "   ".join(f"{k} {v:.1f}%" for k, v in judged.fit.items()))
        print(_floor_line(judged, floor, floor_se, args))
        if small:
            print("  " + _small_gap_words(small, args))
    return 0


def _small_gap_words(small: dict, args) -> str:
    """What a fit a little below the noise floor, by more than chance (``small``: fit points), means."""
    gap = ", ".join(f"{o} {g:.1f} points" for o, g in small.items())
    return (f"this model is a little below the noise floor ({gap}: more than chance, under the 2 points that call "
            f"it far below): a small effect may be missing, such as an accelerometer a few cm off the CG; "
            f"diagnose looks for it: {_diagnose_command(args)}")


def _diagnose_command(args) -> str:
    """The `stid diagnose` command for a fit's own runs, vehicle and model, ready to paste."""
    import shlex

    return shlex.join(["stid", "diagnose", *args.runs, "--vehicle", args.vehicle, "--model", args.model])


def _validation_runs(args, vehicle, fitted):
    if not getattr(args, "validate", None):
        return None
    from pathlib import Path

    from stid.errors import InputError
    from stid.load import load_runs, same_data, same_runs

    def refuse(names):
        raise InputError(f"--validate {', '.join(sorted(names))}: the same data as a run fitted to; judge on runs "
                         "the fit did not see (give them only after --validate)")

    both = same_data(list(args.validate), list(args.runs))  # the same file, or a copy of one
    if both:
        refuse({Path(a).name for a, _ in both})
    held = load_runs(args.validate, vehicle)
    both = same_runs(fitted + held, [0] * len(fitted) + [1] * len(held))  # the same samples in other bytes
    if both:
        refuse({both[1][0].name})
    _print_load_warnings(held)
    return held


def _judged_stretches(runs, held: bool):
    """The stretches a fit is judged on: its own runs' (None when they hold none to fit: then
    there is no noise floor), or the held-out runs' (none there is the user's error)."""
    from stid.errors import InputError
    from stid.fit import dataset

    if held:
        return dataset.held_out_stretches(runs)
    try:
        return dataset.dynamic_stretches(runs)
    except InputError:
        return None


def _judge(res, model_name, vehicle, stretches, held, floor=None):
    """The fit judged on the held-out runs' ``stretches`` (or its own), and the noise floor of
    those (``floor``: a Future of it, when a worker computes it)."""
    from stid.analysis.noise_floor import noise_floor_uncertainty

    if stretches is None:
        nan = {"ay": float("nan"), "r": float("nan")}
        return res, nan, dict(nan)
    floor, se = floor.result() if floor is not None else noise_floor_uncertainty(stretches)
    if not held or not res.predictions:
        return res, floor, se
    from stid.fit.validate import judge_on
    from stid.models.model import Model

    return judge_on(res, Model(model_name, vehicle), stretches), floor, se


def _floor_line(res, floor, se, args) -> str:
    if not res.fit or not all(k in floor for k in res.fit):
        return ""
    import math

    known = [o for o in floor if math.isfinite(floor[o])]
    if not known:
        from stid.analysis.noise_floor import floor_words

        return "  " + floor_words(floor, se)
    from stid.analysis.noise_floor import below_floor

    short = below_floor(res, floor, se)
    on = "on the held-out runs" if getattr(args, "validate", None) else "on this data"
    text = (f"  noise floor (what a correct model reaches {on}): "
            + "   ".join(f"{o} {floor[o]:.1f}% +- {se[o]:.2f}" if o in se else f"{o} {floor[o]:.1f}%" for o in known))
    if len(known) < len(floor):
        from stid.analysis.noise_floor import floor_words

        text += "; " + floor_words({o: v for o, v in floor.items() if o not in known}, se)
    from stid.analysis.noise_floor import ABOVE_WORDS, above_floor

    above = above_floor(res.fit, floor, se)
    if above:
        text += ("\n  this model is above it (" + ", ".join(f"{o} {g:.1f} points" for o, g in above.items())
                 + f"): {ABOVE_WORDS}")
    if short:
        text += "\n  " + _below_floor_words(short, res.converged, args)
    return text


def _below_floor_words(short: dict, converged: bool, args) -> str:
    """What a fit far below the noise floor (``short``: fit points per output) means."""
    gap = ", ".join(f"{o} {g:.1f} points" for o, g in short.items())
    if not converged:
        return f"this fit is far below the noise floor ({gap}) because the solver did not converge, not because " \
               "the model must lack something"
    return (f"this model is far below the noise floor ({gap}): something is missing, and its intervals hold only "
            "if the model were right (a model that misses an effect bends its parameters to make up for it, by "
            "more than the intervals show). See what: " + _diagnose_command(args))


def _vehicle_and_runs(args, chain_warning: bool = False):
    """The vehicle file and the runs of a command, with the loaders' warnings printed.
    ``chain_warning``: also the warning that the runs declare no sensor chain (fit and report
    carry it in their results; a command that shows no single fit must say it here, or a
    sensor filter it leaves out reads as a servo lag without a word)."""
    from stid import sensor_chain
    from stid.load import load_runs
    from stid.vehicle_file import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    _check_models(args, vehicle)  # (a misspelt model is heard of before a bag's notes, not after)
    runs = load_runs(args.runs, vehicle)
    _print_load_warnings(runs)
    if chain_warning:
        for w in sensor_chain.undeclared_warnings(runs, vehicle):
            print(f"warning: {w}", file=sys.stderr)
    return vehicle, runs


def _check_models(args, vehicle) -> None:
    """The command's model names, checked against the catalogue (InputError for one it lacks)."""
    from stid.models.model import Model

    names = getattr(args, "model", None)
    for name in names if isinstance(names, (list, tuple)) else [names]:
        if isinstance(name, str) and not name.split("+")[0].strip().startswith("greybox"):
            Model(name, vehicle)


def _print_load_warnings(runs) -> None:
    """The loaders' warnings and notes, each said once per file: a log a lossy link cut into
    pieces (name#2, #3, ...) gives most of them to every piece."""
    from stid.load import piece_names

    by_file = {}
    for r in runs:
        by_file.setdefault(r.meta.get("source", r.name), []).append(r)
    for pieces in by_file.values():
        for kind in ("warning", "note"):
            said = {}
            for r in pieces:
                for w in r.meta.get(kind + "s", []):
                    said.setdefault(w, []).append(r.name)
            for w, names in said.items():
                who = (f"{names[0]} (all {len(names)} pieces)" if len(names) == len(pieces) > 1
                       else piece_names(names))
                print(f"{kind}: {who}: {w}", file=sys.stderr)


def _cmd_diagnose(args) -> int:
    from stid.diagnose import diagnose
    from stid.present import diagnosis_text
    from stid.progress import Progress

    vehicle, runs = _vehicle_and_runs(args, chain_warning=True)
    with Progress("diagnosing") as prog:
        rounds = diagnose(runs, vehicle, args.model, peel=args.peel, progress=prog)
    if args.json:
        doc = rounds[0].to_json()
        if args.peel:
            doc["steps"] = [d.to_json() for d in rounds]
        doc["unexplained"] = rounds[-1].unexplained.to_json()
        print(_json(doc))
    else:
        print(diagnosis_text(rounds, args.runs, args.vehicle, peel=args.peel))
    return 0


def _cmd_compare(args) -> int:
    from stid.compare import compare
    from stid.present import comparison_text
    from stid.progress import Progress

    vehicle, runs = _vehicle_and_runs(args, chain_warning=True)
    held = _validation_runs(args, vehicle, runs)
    with Progress("comparing") as prog:
        entries = compare(runs, vehicle, args.model or ["bicycle"], method=args.method, progress=prog,
                          validate=held)
    if args.json:
        print(_json({"models": [{k: v for k, v in e.items() if not k.startswith("_")} for e in entries]}))
    else:
        print(comparison_text(entries, args.runs, args.vehicle, validate=args.validate))
    return 0


def _cmd_report(args) -> int:
    from stid.progress import Progress
    from stid.output_paths import check_report_dir

    check_report_dir(args.output, args.overwrite)  # before the imports and the loading: known at once
    from stid.report import write_report

    vehicle, runs = _vehicle_and_runs(args)
    with Progress("writing the report") as prog:
        path = write_report(runs, vehicle, args.output, args.model, progress=prog, run_paths=args.runs,
                            vehicle_path=args.vehicle, overwrite=True)
    print(path)
    return 0


def _cmd_plan(args) -> int:
    from stid.errors import InputError
    from stid.load import load_runs
    from stid.models.model import Model
    from stid.plan import check_grip, datasheet_noise, parse_manoeuvre, plan_report
    from stid.vehicle_file import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    model = Model(args.model, vehicle)
    params = model.defaults()  # (the vehicle file's [params] init where it gives one)
    warnings = []
    if args.params_from:
        from stid.fit.fitting import fit
        from stid.plan import missing_effect_warning

        params_runs = load_runs(args.params_from, vehicle)
        fitted = fit(params_runs, vehicle, args.model, "time")
        params.update(fitted.all_params())
        warnings += missing_effect_warning(fitted, params_runs, args.params_from, args.vehicle)
        params_source = f"a fit to {', '.join(args.params_from)}" + (
            "" if fitted.converged else " that did not converge (its values are where the solver stopped)")
    else:
        params_source = "the model's defaults and the vehicle file's [params]"
    if not args.manoeuvre:
        raise InputError("give at least one --manoeuvre, e.g. --manoeuvre speed=4,amp=2deg,bw=4,dur=60")
    manoeuvres = [parse_manoeuvre(m) for m in args.manoeuvre]
    if args.noise_from:
        # a run that drove: its fit residuals (model error + sensor noise), not only the
        # stand-still's sensor noise, which assumes the model exact and predicts too little
        from stid.plan import noise_from_runs

        noise, source, fitted, said = noise_from_runs(load_runs([args.noise_from], vehicle), vehicle, args.model,
                                                      args.noise_from, args.vehicle)
        if fitted and not args.params_from:
            params.update(fitted)
            params_source = f"the fit to {args.noise_from}"
        warnings += [w for w in said if w not in warnings]
    else:
        noise = datasheet_noise(vehicle=vehicle)
        source = "datasheets (ADXL335, LISY300AL, 12-bit ADC)"
    targets = {}
    for t in args.target or []:
        try:
            name, val = t.split("=")
            targets[name.strip()] = float(val.strip().rstrip("%")) / 100
        except ValueError:
            raise InputError(f"--target {t!r}: write NAME=PERCENT, e.g. Iz=5%") from None
        if not 0 < targets[name.strip()] < 1:  # (nan fails this too)
            raise InputError(f"--target {t!r}: the target is a standard error in percent of the value, "
                             "above 0 and below 100, e.g. Iz=5%")
    for m in manoeuvres:
        check_grip(model, params, m)
    text, doc = plan_report(model, params, manoeuvres, noise, targets, source, params_source, warnings)
    print(_json(doc) if args.json else text)
    return 0


def _cmd_batch(args) -> int:
    from stid.batch import batch_cli

    return batch_cli(args.runs, args.vehicle, args.model, args.method, args.workers, args.scheduler,
                     args.output, args.diagnose, args.overwrite)


def _cmd_calibrate(args) -> int:
    from stid.calibrate import calibrate_cli

    return calibrate_cli(args.standstill, args.vehicle, args.circle or (), args.output, args.overwrite)


def _cmd_live(args) -> int:
    from stid.live.follow import live
    from stid.live.targets import choose, parse_cli
    from stid.models.model import Model
    from stid.vehicle_file import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    targets, where = choose(Model(args.model, vehicle), parse_cli(args.target), vehicle.targets)
    if not args.every > 0:
        from stid.errors import InputError

        raise InputError(f"--every {args.every:g}: give the seconds between updates, above 0 (e.g. 2)")
    if args.check:  # stid-log --live checks the view's arguments before it opens the port
        return 0
    if not args.follow and not Path(args.run).exists():  # (followed, it may not be there yet)
        from stid.errors import InputError

        raise InputError(f"{args.run} does not exist (to wait for a file a logger is about to write, add --follow)")
    return live(args.run, vehicle, args.model, targets, where, follow=args.follow, every=args.every,
                web_port=args.web, json_lines=args.json, from_logger=args.from_logger,
                diagnose=not args.no_diagnose)


def _cmd_serve(args) -> int:
    from stid import serve

    if args.stop:
        return serve.stop_server()
    if not args.idle > 0:
        from stid.errors import InputError

        raise InputError(f"--idle {args.idle:g}: give the minutes without a command after which the server stops (> 0)")
    return serve.serve(main_here, idle_s=args.idle * 60)


def _cmd_repair(args) -> int:
    from host.repair import repair_cli

    return repair_cli(args.file, args.output, args.hello_from)


USAGE = """\
stid turns runs logged from an RC car (stid-log's MCAP, CSV, or a ROS bag) into a measured
vehicle: cornering stiffness per axle [N/rad], yaw inertia [kg m^2], and the
physical effects the plain single-track model misses.

A first session:
  stid fit RUN.mcap --vehicle car.toml             fit the single-track model
  stid diagnose RUN.mcap --vehicle car.toml --peel  what is missing, and where
  stid fit RUN.mcap --vehicle car.toml --model bicycle+actuator_lag
  stid report RUN.mcap --vehicle car.toml -o out/   the whole story as one HTML page
No car yet? `make demo` runs all of it on the simulated car."""


class _Parser(argparse.ArgumentParser):
    """Help that ends with the catalogue of effects (looked up only when help is shown,
    so a command does not pay for importing every effect)."""

    def format_help(self) -> str:
        text = super().format_help()
        if self.prog != "stid":
            return text
        import textwrap

        from stid.errors import StidError
        from stid.models.effect import available_effects

        lines = ["", "effects a model can add (--model bicycle+EFFECT+...), with their parameters:"]
        try:
            effects = available_effects()
        except StidError as e:  # a user's effect file (STID_EFFECTS) that cannot load: say so here
            return text + "\n".join(lines + textwrap.wrap(f"(cannot list them: {e})", 78, initial_indent="  ",
                                                            subsequent_indent="  ")) + "\n"
        for name, cls in sorted(effects.items()):
            doc = (getattr(cls, "physics", "") or "").split(". ")[0].strip().rstrip(".") + "."
            params = ", ".join(f"{q.name} [{q.unit}]" for q in cls.params)
            lines.append(f"  {name}: {params}")
            lines.extend(textwrap.wrap(doc, 78, initial_indent="      ", subsequent_indent="      "))
        return text + "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    from stid import __version__

    ap = _Parser(prog="stid", description=USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action="version", version=f"stid {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=argparse.ArgumentParser)
    sub.required = True

    p = sub.add_parser("flash", help="precompile the firmware and copy it to a board")
    p.add_argument("--board", required=True, choices=["pico", "esp32"])
    p.add_argument("--port", help="serial port of the board (default: mpremote's auto)")
    p.add_argument("--rate", type=int, default=500, help="sample rate [Hz] (default 500)")
    p.add_argument("--batch", type=int, default=10, help="samples per frame (default 10)")
    p.add_argument("--wheels", type=int, default=1, choices=[1, 4],
                   help="hall sensors: 1 (rear left) or 4 (the board's four-wheel pins) (default 1)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the flash as a shell script (run it as printed to flash), do nothing")
    p.add_argument("--build-dir", type=Path, default=None,
                   help="folder for the compiled files (default: a temporary one; with --dry-run "
                        "./stid-flash-BOARD, which the printed script creates)")
    p.set_defaults(func=_cmd_flash)

    p = sub.add_parser("export", help="write a logged run as CSV in SI units (the import contract)")
    p.add_argument("run", help="a run: RUN.mcap written by stid-log, a ROS bag (docs/ros.md) or another logger's CSV")
    p.add_argument("--csv", required=True, help="output CSV path (- for stdout)")
    p.add_argument("--vehicle", help="vehicle TOML (steering and sensor calibration; default: datasheet values)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing CSV (never a recorded run)")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser("fit", help="fit a model to runs: parameters with uncertainty, fit percent, warnings")
    p.add_argument("runs", nargs="+", metavar="RUN", help=RUNS_HELP)
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m]")
    p.add_argument("--model", default="bicycle", help="bicycle or bicycle+effect+... (default bicycle)")
    p.add_argument("--method", default="auto", choices=["auto", "steady", "freq", "freq-study", "time", "two-step"],
                   help="auto: two-step when there are steady circles and a constant-speed stretch")
    p.add_argument("--validate", nargs="+", metavar="RUN", help="judge the fit on these runs (not fitted to)")
    p.add_argument("--json", action="store_true", help="machine-readable result on stdout (nothing else)")
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser("diagnose", help="name the physical effect the model is missing")
    p.add_argument("runs", nargs="+", metavar="RUN", help=RUNS_HELP)
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m]")
    p.add_argument("--model", default="bicycle", help="the model to diagnose (default bicycle)")
    p.add_argument("--peel", action="store_true", help="add the winner and diagnose again until nothing is missing")
    p.add_argument("--json", action="store_true", help="machine-readable result on stdout (nothing else)")
    p.set_defaults(func=_cmd_diagnose)

    p = sub.add_parser("compare", help="compare models: fit, AIC/BIC, where the error lives, residual analysis")
    p.add_argument("runs", nargs="+", metavar="RUN", help=RUNS_HELP)
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m]")
    p.add_argument("--model", action="append", help="a model to compare (repeat the option)")
    p.add_argument("--method", default="time", choices=["time", "freq"], help="how each model is fitted")
    p.add_argument("--validate", nargs="+", metavar="RUN", help="judge every model on these runs (not fitted to)")
    p.add_argument("--json", action="store_true", help="machine-readable result on stdout (nothing else)")
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser("report", help="self-contained HTML report: fits, diagnosis, figures, the error falling")
    p.add_argument("runs", nargs="+", metavar="RUN", help=RUNS_HELP)
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m]")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="directory for report.html")
    p.add_argument("--model", default="bicycle", help="the starting model (default bicycle)")
    p.add_argument("--overwrite", action="store_true", help="replace a report.html already in DIR")
    p.set_defaults(func=_cmd_report)

    p = sub.add_parser("plan", help="predict parameter uncertainty for planned manoeuvres (Cramér-Rao bound)")
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m]")
    p.add_argument("--model", default="bicycle")
    p.add_argument("--manoeuvre", action="append", metavar="SPEC",
                   help="random steer: speed=M/S,amp=DEG deg,bw=HZ,dur=S (repeat for several)")
    p.add_argument("--noise-from", metavar="RUN",
                   help="noise level from this run: the residuals of a fit to it (model error + sensor noise), "
                        "or its stand-still when it never drives")
    p.add_argument("--params-from", nargs="+", metavar="RUN", help="parameter values from fitting these runs")
    p.add_argument("--target", action="append", metavar="NAME=PCT", help="e.g. Iz=5%%: what to add to reach it")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_plan)

    p = sub.add_parser("live", help="while a run is recorded: precision per parameter, what to drive next, done")
    p.add_argument("run", metavar="RUN", help="a run being written: stid-log's MCAP (or a ROS 2 bag, once readable)")
    p.add_argument("--vehicle", required=True, help="vehicle TOML: name, mass [kg], a, b [m] (and [targets])")
    p.add_argument("--model", default="bicycle", help="bicycle or bicycle+effect+... (default bicycle)")
    p.add_argument("--target", action="append", metavar="NAME=PCT",
                   help="e.g. Iz=3%%: the 95%% interval's half-width to reach, in %% of the value (repeat; default: "
                        "the vehicle file's [targets], else 5%% for every parameter positive by nature)")
    p.add_argument("--follow", action="store_true", help="keep reading the file as it grows (else: one update)")
    p.add_argument("--every", type=float, default=2.0, help="seconds between updates (default 2)")
    p.add_argument("--web", type=web_port, nargs="?", const=0, metavar="PORT",
                   help="also serve the live view on http://127.0.0.1:PORT/ (no PORT: a free one, printed)")
    p.add_argument("--json", action="store_true", help="one JSON document per update on stdout (nothing else)")
    p.add_argument("--no-diagnose", action="store_true", help="do not run stid diagnose in the background")
    p.add_argument("--from-logger", action="store_true", help=argparse.SUPPRESS)  # stid-log --live's child
    p.add_argument("--check", action="store_true", help=argparse.SUPPRESS)  # only check the arguments
    p.set_defaults(func=_cmd_live)

    p = sub.add_parser("batch", help="fit (and diagnose) many runs in parallel; one table and drift plots",
                       epilog="The table's columns, one row per run: each parameter's value with _se, _lo and _hi "
                              "(its standard error and 95% interval; empty where the data do not determine it) in "
                              "SI units (Cf, Cr: N/rad per axle; Iz: kg m^2; a lag: s; x_acc: m), fit_ay and fit_r "
                              "[%], speed [m/s], below_floor (fit points short of the run's noise floor, where the "
                              "model misses an effect), warnings and warning_text, missing_effect (--diagnose), "
                              "error, skipped (a run that stands still throughout), seconds (its time to fit).")
    p.add_argument("runs", metavar="DIR_OR_GLOB", nargs="+",
                   help="directories of runs, globs like 'logs/*.mcap', or run files (as a shell expands a glob)")
    p.add_argument("--vehicle", required=True, help="the car's vehicle file (mass, a, b; docs/examples/rc8.toml)")
    p.add_argument("--model", default="bicycle", help="the model each run is fitted with (default bicycle)")
    p.add_argument("--method", default="time", choices=["time", "freq", "auto"],
                   help="the fit's method (default time: every run by the same one, so the rows compare; stid "
                        "fit's default is auto, which picks by what a run holds)")
    p.add_argument("--diagnose", action="store_true", help="also name the missing effect of each run")
    p.add_argument("--workers", type=int, help="local processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("-o", "--output", default="stid-batch.csv", help="results table (.csv or .parquet)")
    p.add_argument("--overwrite", action="store_true", help="replace the table and its drift plot if they exist")
    p.set_defaults(func=_cmd_batch)

    p = sub.add_parser("calibrate", help="sensor zeros and mounting from a stand-still run (+ steering from circles)")
    p.add_argument("standstill", help="STANDSTILL.mcap: the car at rest on level ground, engine off")
    p.add_argument("--vehicle", required=True, help="vehicle TOML to update ([sensors], [steering])")
    p.add_argument("--circle", action="append", metavar="RUN", help="slow steady circles for the steering calibration")
    p.add_argument("-o", "--output", help="write here instead of updating the vehicle file")
    p.add_argument("--overwrite", action="store_true", help="replace an existing -o file")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("serve", help="keep stid loaded: commands run meanwhile start in ~0.1 s instead of ~0.9 s")
    p.add_argument("--idle", type=float, default=30.0, metavar="MIN",
                   help="stop after this many minutes without a command (default 30)")
    p.add_argument("--stop", action="store_true", help="stop this user's running servers")
    p.set_defaults(func=_cmd_serve)

    p = sub.add_parser("repair", help="rewrite a cut-short or damaged log into a complete one (what fails its "
                                      "checks is left out and named)")
    p.add_argument("file")
    p.add_argument("-o", "--output", help="output path (default: FILE with .repaired.mcap)")
    p.add_argument("--hello-from", metavar="EARLIER.mcap|V.toml",
                   help="a log with no HELLO: take the configuration from an earlier log of the same board, or "
                        "from the [board] table a vehicle file declares (docs/hello_in_vehicle_file.md)")
    p.set_defaults(func=_cmd_repair)

    for p in sub.choices.values():
        p.add_argument("--version", action="version", version=f"stid {__version__}")
    ap.commands = sub.choices
    return ap


def main(argv=None) -> int:
    """The console command: in a warm server when one of this code runs (stid.serve), else here."""
    try:  # (Ctrl-C while the server is looked for or the parser built: before main_here's own try)
        if argv is None and len(sys.argv) > 1 and not sys.argv[1].startswith("-"):  # (`stid --help`: at once)
            from stid.serve import run_in_server

            rc = run_in_server(sys.argv[1:])
            if rc is not None:
                return rc
        return main_here(argv)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def main_here(argv=None) -> int:
    from stid.interrupts import interrupts_kept

    with interrupts_kept():  # (a Ctrl-C that lands where Python drops exceptions: a fork's handlers)
        return _main_here(argv)


def _main_here(argv=None) -> int:
    ap = build_parser()
    args, extra = ap.parse_known_args(argv)
    if extra:  # said by the command it was given to ("stid fit: error: ..."), with its usage
        ap.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        rc = args.func(args)
        if sys.stdout is not None:  # (None: started with stdout closed, `>&-`; print() writes nothing then)
            sys.stdout.flush()  # inside the try: a closed pipe shows here, not at interpreter exit
        # what is left lives until the process ends: frozen, it is spared the interpreter's
        # final garbage collections (0.15 s of every command once numba is loaded)
        gc.freeze()
        return rc
    except (StidError, HostError) as e:
        print(f"stid {args.command}: error: {e}", file=sys.stderr)
        return e.exit_code
    except BrokenPipeError:
        # the reader went away (`stid ... | head -1`): nothing more to say, and nothing to flush
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:  # the environment refused something (permissions, full disk)
        where = f": {e.filename}" if e.filename else ""
        print(f"stid {args.command}: error: {e.strerror or e}{where}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
