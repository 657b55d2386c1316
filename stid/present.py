"""Human-readable text for diagnose and compare results (the numbers live in the
result objects; this only lays them out, for a person who reads it once)."""

from __future__ import annotations

import math
import shlex
import textwrap

import numpy as np

from stid.analysis.noise_floor import above_floor, floor_words
from stid.fit.result import at_resolution
from stid.models.params import unit_suffix

WIDTH = 100


def _pct(x) -> str:
    return f"{x:5.1f}%" if np.isfinite(x) else "   - "


def _wrap(text: str, indent: str = "  ", first: str | None = None) -> list:
    return textwrap.wrap(text, WIDTH, initial_indent=first if first is not None else indent,
                         subsequent_indent=indent + "  ") or [indent]


def _params_with_intervals(res, owner=None) -> str:
    out = []
    se_of = dict(zip(res.names, res.stderr))
    for n, v in res.params().items():
        if owner is not None and res.owners.get(n) != owner:
            continue
        ci = res.interval_of(n)
        se = se_of.get(n, float("nan")) if ci else float("nan")
        where = (f"[{at_resolution(ci[0], se)}, {at_resolution(ci[1], se)}]" if ci
                 else f"(no interval: {res.undetermined.get(n, '')})")
        out.append(f"{n} = {at_resolution(v, se)} {where}{unit_suffix(res.units.get(n, ''))}")
    return ", ".join(out)


def _command(runs, vehicle_path, *rest) -> str:
    parts = ["stid", *rest[:1], *(runs or ["RUN..."]), "--vehicle", vehicle_path or "V.toml", *rest[1:]]
    return " ".join(shlex.quote(str(p)) for p in parts)


def _screened_line(d) -> str:
    """The candidates the linearised screen kept from a full fit, grouped by why."""
    groups = {"chance": [], "small": [], "capped": []}
    # largest predicted gain first (the screen ranks by its test statistic, which the points
    # shown here need not follow)
    for c in sorted(d.candidates, key=lambda c: -max(c.gain.values()) if c.gain else 0.0):
        if c.result is None and not c.skipped:
            gain = max(c.gain.values()) if c.gain else 0.0
            groups[c.screen.get("why", "small")].append(
                f"{c.effect} ({gain:.1f} points)" if c.screen.get("why") == "capped" else c.effect)
    parts = []
    if groups["capped"]:
        from stid.search.screen import MAX_FULL_FITS  # (compare, which only needs the layout, skips the search)

        # (ranked by the step's likelihood ratio, both outputs together; the points are its predicted
        # gain in the better one, so a candidate below may show more points than one fitted)
        parts.append(f"ranked below the {MAX_FULL_FITS} best by likelihood ratio (predicted gain, fit points): "
                     + ", ".join(groups["capped"]))
    if groups["small"]:
        parts.append("would gain under 0.25 fit points: " + ", ".join(groups["small"]))
    if groups["chance"]:
        parts.append("within chance: " + ", ".join(groups["chance"]))
    if not parts:
        return ""
    return f"not fitted (judged by a linearised step from {d.model}): " + "; ".join(parts)


def _unsettled(d) -> list:
    """The candidates of round ``d`` that gained fit points but whose fits did not converge: until
    they do, the catalogue is not shown to lack the missing effect."""
    return [c for c in d.candidates if c.result is not None and not c.result.converged
            and max(c.gain.values(), default=0.0) > 0]


def diagnosis_text(rounds, runs=None, vehicle_path=None, peel: bool = False) -> str:
    """What to add first, why, what the others are, and the next command."""
    lines = []
    see_below = False  # a round's verdict points to the 'unexplained' section: it must be there
    for k, d in enumerate(rounds):
        head = "" if k == 0 else f"step {k + 1}: "
        n = len(d.base.predictions)
        lines.append(f"{head}model {d.model}: fit ay {d.base.fit['ay']:.1f}%, r {d.base.fit['r']:.1f}%   "
                     f"{floor_words(d.floor, d.floor_se, d.base.fit)}   [{n} stretch{'es' if n != 1 else ''} at "
                     f"{_speeds(d)}]")
        if not d.base.converged:
            lines.extend(_wrap(d.base.verdict_line(), first="  "))
        if any(c.skipped or c.result is not None for c in d.candidates):
            lines.append(f"  {'candidate':<22}{'fit ay':>8}{'fit r':>8}   verdict")
        for c in d.candidates:
            if c.skipped:
                lines.extend(_wrap(f"{c.effect:<22}{'':>8}{'':>8}   not tested: {c.skipped}"))
                continue
            if c.result is None:  # the screen's verdict, in one line below the table
                continue
            named = f"NAMED with {c.pair_with}, fitted jointly: " if c.pair_with and c is not d.best else "NAMED: "
            verdict = named + c.p_words() if c.significant else c.why_not
            lines.extend(_wrap(f"{c.effect:<22}{_pct(c.result.fit['ay']):>8}{_pct(c.result.fit['r']):>8}   "
                               f"{verdict}", indent="  " + " " * 41, first="  "))
        screened = _screened_line(d)
        if screened:
            lines.extend(_wrap(screened, indent="    ", first="  "))
        best = d.best
        known = [o for o in ("ay", "r") if math.isfinite(d.floor[o])]
        if best is not None:
            # a later step names more: these numbers are of a model still missing it (it may move them)
            later = any(r.best is not None for r in rounds[k + 1:])
            lines.extend(_named_lines(d, f"95%, in {d.named_model}: step {k + 2} adds more" if later else "95%"))
        elif known and above_floor(d.base.fit, d.floor, d.floor_se):
            lines.extend(_wrap("=> nothing more is named: the model fits above the noise floor, which then cannot "
                               "say whether something is still missing", first="  "))
        elif known and all(d.base.fit[o] >= d.floor[o] - 0.5 for o in known) and d.base.delay_words():
            # a delay gains a fraction of a fit point and moves Iz by several percent: not "nothing missing"
            lines.extend(_wrap("=> no effect gains fit points: the model is at the noise floor, but "
                               + d.base.delay_words(), first="  "))
        elif known and all(d.base.fit[o] >= d.floor[o] - 0.5 for o in known):
            lines.append("  => nothing is missing that this data can show: the model is at the noise floor"
                         + ("" if len(known) == 2 else f" of {known[0]} (the other has none)"))
            loose = [o for o in known if d.base.fit[o] - d.floor[o] > 0.5]
            if loose:  # above it, within the floor's own uncertainty: a floor this loose says little
                lines.extend(_wrap("(it fits " + ", ".join(
                    f"{o} {d.base.fit[o] - d.floor[o]:.1f} points above it, within the floor's +-"
                    f"{2.576 * d.floor_se.get(o, float('nan')):.1f}" for o in loose)
                    + " (99%): on this data the floor is poorly known, and a small gap could hide in it)",
                    indent="    ", first="    "))
        elif not known:
            see_below = True
            lines.extend(_wrap("=> nothing named, and with no noise floor on this data nothing says how far "
                               f"{d.model} is from a correct model (see 'unexplained' below)", first="  "))
        elif _unsettled(d):
            see_below = True
            lines.extend(_wrap("=> nothing is named, and the catalogue is not ruled out: the fit of "
                               + ", ".join(f"{d.model}+{c.effect} (ay {c.gain['ay']:+.1f}, r {c.gain['r']:+.1f} "
                                           "points where it stopped)" for c in _unsettled(d))
                               + " did not converge, so what it explains is not known; fit it with 'stid fit "
                               "--model' and read why it stopped (see 'unexplained' below)", first="  "))
        else:
            see_below = True
            tried = [c for c in d.candidates if c.pairs is not None]
            lines.extend(_wrap("=> no effect of the catalogue explains the remaining error"
                               + "".join(f", alone or paired with {c.effect}" for c in tried[:1])
                               + " (see 'unexplained' below)", first="  "))
        lines.append("")
    last = rounds[-1]
    u = last.unexplained
    if u is not None and u.where and (see_below or u.significant or any(v > 0.5 for v in u.gap.values())):
        lines.append(f"unexplained after {u.model}" + (" (significant)" if u.significant else "") + ":")
        for w in u.where:
            lines.extend(_wrap("- " + w, indent="    ", first="  "))
        if u.significant and not _unsettled(last):
            lines.extend(_wrap("an effect the catalogue lacks: write it (docs/writing_an_effect.md), hide it in "
                               "the simulator (stid-sim --effect-file) and see it found", first="  "))
        lines.append("")
    final = last.named_model
    if last.best is not None and not peel:
        nxt = _command(runs, vehicle_path, "diagnose", "--model", final)
        lines.append(f"next: {nxt}")
    else:  # the chain is complete (or nothing was missing): fit it, with intervals
        lines.append(f"next: {_command(runs, vehicle_path, 'fit', '--model', final)}")
    return "\n".join(lines).rstrip()


def _speeds(d) -> str:
    """The speeds of the round's data (a range where a stretch's speed varies within it)."""
    if d.stretches:
        from stid.analysis.speeds import stretch_speeds

        return stretch_speeds(d.stretches)
    return ", ".join(f"{v:g}" for v in sorted({round(p.vx, 1) for p in d.base.predictions})) + " m/s"


def _named_lines(d, which: str = "95%") -> list:
    """What a round names: the best effect, or the pair it is named in, with why and the numbers
    (``which``: what the intervals are, said after them)."""
    best = d.best
    same = [c.effect for c in d.same_symptom]
    also = f" ({', '.join(same)}: the same symptom, not separate effects)" if same else ""
    if best.pair_with:
        pair = best.pairs.named
        out = _wrap(f"=> add {best.effect} and {best.pair_with} together{also}: {best.effect} alone is bent "
                    f"({best.evidence_alone.reason}); fitted jointly, {pair.why}", first="  ")
        partner = next(c for c in d.candidates if c.effect == best.pair_with)
        for c in (best, partner):
            out += _wrap(c.explanation, indent="     ")
        for e in (best.effect, best.pair_with):
            out += _wrap(f"{e}: {_params_with_intervals(pair.result, e)} ({which}, fitted jointly)", indent="     ")
        return out
    out = _wrap(f"=> add {best.effect} first{also}", first="  ")
    out += _wrap(best.explanation, indent="     ")
    out += _wrap(f"{best.effect}: {_params_with_intervals(best.result, best.effect)} ({which})", indent="     ")
    return out


def _which(passed: dict) -> str:
    """'yes' (every output), 'ay only', or 'no'."""
    ok = [o for o, v in passed.items() if v]
    return "yes" if len(ok) == len(passed) else f"{' '.join(ok)} only" if ok else "no"


def comparison_text(entries, runs=None, vehicle_path=None, validate=None) -> str:
    """One table: headers above the rows, full model names, then the verdict (and the command
    to run next: on the same files, or on the held-out ones ``validate`` where the models were
    judged there)."""
    lines = []
    names = [e["model"] for e in entries]
    w = max(14, max(len(n) for n in names) + 2)
    validated = entries[0].get("validated_on")
    # (as given: a held-out sessC/rs5.mcap read as "rs5.mcap", the name of a fitted run too)
    where = f"judged on {', '.join(map(str, validate or validated))} (not fitted to)" if validated else \
        "judged on the fitted runs"
    # the BIC shown is the one the verdict takes, on the effective samples (a trial read the verdict's
    # "on 341 effective samples" beside a column whose penalty counted 43,000)
    eff = all("bic_effective" in e for e in entries)
    lines.append(f"fit percent {where}; AIC/BIC from the Gaussian likelihood of the fit"
                 + ("" if not validated else " (on the fitted runs)")
                 + ("; BIC on the effective samples (the residuals' over their correlation time)" if eff else ""))
    lines.append(f"{'model':<{w}}{'fit ay':>8}{'fit r':>8}{'AIC':>12}{'BIC':>12}  residual white   indep. of steer")
    for e in entries:
        white, indep = _which(e["white"]), _which(e["independent"])
        lines.append(f"{e['model']:<{w}}{_pct(e['fit']['ay']):>8}{_pct(e['fit']['r']):>8}{e['aic']:12.0f}"
                     f"{(e['bic_effective'] if eff else e['bic']):12.0f}  {white:<15}  {indep}")
    for e in entries:
        if not e.get("converged", True):
            lines.extend(_wrap(f"{e['model']} did not converge: its row is where the solver stopped "
                               f"({e['status']})", indent="  ", first=""))
    fl, se = entries[0]["noise_floor"], entries[0].get("noise_floor_stderr", {})
    if all(math.isfinite(v) for v in fl.values()):
        lines.append(f"{'noise floor':<{w}}{_pct(fl['ay']):>8}{_pct(fl['r']):>8}   (what a correct model reaches; "
                     f"+-{se.get('ay', float('nan')):.2f} / {se.get('r', float('nan')):.2f})")
    else:
        lines.extend(_wrap(floor_words(fl, se), indent="  ", first=""))
    lines.extend(_wrap("(white: residual autocorrelation inside the 99% band; indep.: residual-steer "
                       "cross-correlation inside it. At the noise floor a residual may still be coloured: the "
                       "sensor noise is filtered too)", indent="", first=""))
    lines.append("")
    lines.append(_verdict(entries, validate or runs, vehicle_path, held_out=bool(validate)))
    for title, key in (("fit per frequency band", "by_band"), ("fit per |ay| bin", "by_ay"), ("fit per run", "by_run")):
        lines.append("")
        lines.append(f"{title} (ay / r):")
        cw = max(16, max(len(n) for n in names) + 2)
        lw = max([28] + [len(str(row)) + 2 for row in entries[0][key]])  # a long run name keeps its column
        lines.append(f"  {'':<{lw}}" + "".join(f"{n:<{cw}}" for n in names))
        for row in entries[0][key]:
            cells = "".join(f"{_pct(e[key][row]['ay']).strip() + ' / ' + _pct(e[key][row]['r']).strip():<{cw}}"
                            for e in entries)
            lines.append(f"  {row:<{lw}}{cells}")
    return "\n".join(lines)


def _verdict(entries, runs=None, vehicle_path=None, held_out: bool = False) -> str:
    fl, se = entries[0]["noise_floor"], entries[0].get("noise_floor_stderr", {"ay": 0.0, "r": 0.0})
    # a fit that did not converge is no candidate for the best (unless none did)
    best = min([e for e in entries if e.get("converged", True)] or entries,
               key=lambda e: e.get("bic_effective", e["bic"]))

    known = [o for o in ("ay", "r") if math.isfinite(fl[o])]

    def short(e):
        return {o: fl[o] - e["fit"][o] for o in known if fl[o] - e["fit"][o] > max(0.5, 2.576 * se.get(o, 0.0))}

    gap = short(best)
    # one model has no rival to be best of: the verdict is its distance to the floor alone
    one = len(entries) == 1
    text = f"verdict: {best['model']}" + ("" if one else " is the best of these by BIC"
                                          + (f" (on {best['effective_samples']} effective samples: the residuals' "
                                             "samples over their correlation time)" if "effective_samples" in best
                                             else ""))
    if not known:
        if one:
            return text + ": with no noise floor on this data, nothing says how close it comes to a correct model"
        return text + " (with no noise floor on this data, nothing says how close it comes to a correct model)"
    above = above_floor(best["fit"], fl, se)
    if not gap and above:
        text += ((" fits" if one else " and fits") + " above the noise floor in " + ", ".join(above)
                 + ": the floor misses a nonlinearity this data holds (such as tyres deep in their saturation), "
                 "so it cannot say whether something is still missing")
    elif not gap:
        text += ((" reaches" if one else " and reaches") + " the noise floor"
                 + (f" of {', '.join(known)} (there is none for the other)" if len(known) < 2 else "")
                 + ": nothing more this data can show")
    elif held_out:  # (short on runs it was not fitted to: fit those, and see what moved)
        single = runs is not None and len(runs) == 1
        held, they, hold, them = ("run", "it", "holds", "it") if single else ("runs", "they", "hold", "them")
        text += ((" stays " if one else " but stays ") + ", ".join(f"{o} {g:.1f} points" for o, g in gap.items())
                 + f" short of the noise floor on the held-out {held}: {they} {hold} what the fitted ones do not (the "
                 f"car changed between them, or {they} drove what shows an effect); fit {them} alone: a parameter that "
                 "moved from the fitted runs' is the car that changed, and a fit still far below its floor there is "
                 "an effect to diagnose:\n"
                 + "next: " + _command(runs, vehicle_path, "fit", "--model", best["model"]))
    else:
        text += ((" stays " if one else " but stays ") + ", ".join(f"{o} {g:.1f} points" for o, g in gap.items())
                 + " short of the noise floor; to see what is missing:\n"
                 + "next: " + _command(runs, vehicle_path, "diagnose", "--model", best["model"]))
    return text
