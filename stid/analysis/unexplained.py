"""What remains after the last model, and where: the ``unexplained`` of
shared/DESIGN.md, in words an engineer acts on.

The yardstick everywhere is the noise floor's own error (stid.analysis.noise_floor:
what a correct model leaves), so "where" means "where the model's error exceeds what
the data allow": per output, per frequency band, per amplitude (|steer|, |ay|), per
speed (the model refitted at each speed on its own: where its parameters disagree,
the model is wrong in a way that changes with speed), and what the residual follows
(steer, steer rate, ay, r, r/vx, vx, and ax or beta where the log has them)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

OUTS = ("ay", "r")
UNITS = {"ay": "m/s^2", "r": "rad/s"}
BANDS_HZ = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0), (8.0, 25.0))
MIN_GAP = 0.5  # fit points: below this a gap is not worth an engineer's time
Z = 2.576  # 99%


@dataclass
class Unexplained:
    significant: bool
    gap: dict
    where: list
    model: str
    by_band: dict = field(default_factory=dict)  # output -> [(band, model rms, floor rms)]
    by_amplitude: dict = field(default_factory=dict)  # "|steer|"/"|ay|" -> output -> [(bin, rms, rms / output rms)]
    by_speed: list = field(default_factory=list)  # [(label, {param: (value, lo, hi)})]
    follows: dict = field(default_factory=dict)  # output -> [(signal, correlation, band)]
    pairs_tried: dict = field(default_factory=dict)  # an effect not named -> its pair search's JSON

    def to_json(self) -> dict:
        out = {"significant": self.significant, "model": self.model,
               "gap": {k: round(v, 2) for k, v in self.gap.items()}, "where": list(self.where)}
        if self.pairs_tried:  # "the catalogue lacks it" is said after these
            out["pairs_tried"] = self.pairs_tried
        return out


def _residuals(result):
    preds = result.predictions
    e = np.vstack([(p.y - p.yhat)[p.keep] for p in preds])
    return preds, e


def _band_rms(x: np.ndarray, fs: float, lo: float, hi: float) -> float:
    f = np.fft.rfftfreq(len(x), 1 / fs)
    X = np.fft.rfft(x - x.mean())
    m = (f >= lo) & (f < hi) & (f > 0)
    return float(np.sqrt(2 * np.sum(np.abs(X[m]) ** 2)) / len(x))


def _regressors(stretches, preds):
    """Per stretch, the signals a residual may follow, on the kept samples: the model's inputs and
    outputs, and every other channel the log measured (ax, beta) where every stretch has it."""
    other = [n for n in (stretches[0].measured or {}) if all(n in (st.measured or {}) for st in stretches)]
    out = {k: [] for k in ("steer", "steer rate", "ay", "r", "r/vx", "vx", *other)}
    for st, p in zip(stretches, preds):
        k = p.keep
        out["steer"].append(st.steer[k])
        out["steer rate"].append(np.gradient(st.steer, st.dt)[k])
        out["ay"].append(p.yhat[k, 0])  # the model's, not the measured (which holds the residual)
        out["r"].append(p.yhat[k, 1])
        out["r/vx"].append((p.yhat[:, 1] / st.vx_series)[k])
        out["vx"].append(st.vx_series[k])
        for n in other:
            out[n].append(st.measured[n][k])
    return {n: np.concatenate(v) for n, v in out.items()}


EARLY_Z = 3.0  # standard errors: outputs this far ahead of the steer are said
LAGGING = ("actuator_lag", "sensor_delay", "tyre_relaxation")  # effects that delay the outputs after the steer


def describe_unexplained(model_name, result, vehicle, stretches, floor, floor_se, reasons=(),
                         catalogue_done: bool = True, mapper=map, parts=None) -> Unexplained:
    """What the model leaves, and where (``mapper``: over the per-speed refits, as in
    stid.analysis.evidence.fit_groups; ``parts``: those refits when the caller has them)."""
    from stid.analysis.evidence import MATERIAL, disagreements, fit_groups
    from stid.analysis.noise_floor import floor_errors, floor_rate, floor_words
    from stid.analysis.speeds import one_speed_words
    from stid.stats import tau_int

    gap = {o: float(floor[o] - result.fit[o]) for o in OUTS}
    short = [o for o in OUTS if gap[o] > max(MIN_GAP, Z * floor_se.get(o, 0.0))]
    u = Unexplained(significant=bool(short) and catalogue_done, gap=gap, where=[], model=model_name)
    for r in reasons:
        u.where.append(r)
    if not all(np.isfinite(floor[o]) for o in OUTS):
        u.where.append(floor_words(floor, floor_se) + ": what a correct model reaches here is unknown")
        u.where.extend(where_without_floor(model_name, result, vehicle, stretches, mapper, parts))
        return u
    if not short:
        from stid.analysis.noise_floor import ABOVE_WORDS, above_floor

        where = "above" if above_floor(result.fit, floor, floor_se) else "at"
        u.where.append(f"{model_name} is {where} the noise floor of this data: "
                       + ", ".join(f"{o} {result.fit[o]:.1f}% vs {floor[o]:.1f}% (+-{floor_se[o]:.2f})" for o in OUTS)
                       + (f"; {ABOVE_WORDS}" if where == "above" else ""))
        return u
    if not catalogue_done:
        u.where.append("other catalogued effects were not tested on top of it: run diagnose with --peel")
    preds, e = _residuals(result)
    fe, _ = floor_errors(stretches)
    fs = 1.0 / stretches[0].dt
    # -- which output, how far
    for o in short:
        u.where.append(f"{o} fits {result.fit[o]:.1f}%, {gap[o]:.1f} points short of the noise floor "
                       f"({floor[o]:.1f}% +- {floor_se[o]:.2f})")
    # -- when: outputs that answer the steer before the model has them are no effect of the car's (no
    # catalogue effect moves the steer later), and the gap then sent a trial user to write one
    seen = result.extra.get("delay_seen_ms")
    if seen is not None and seen[0] < 0 and abs(seen[0]) >= EARLY_Z * seen[1]:
        lags = [e for e in model_name.split("+")[1:] if e in LAGGING]
        said = f"the outputs answer the steer {abs(seen[0]):.2f} ms (std. error {seen[1]:.2f}) earlier than {model_name} has them"
        if lags:  # (its own lag is too much: a relaxation standing in for a servo lag left the outputs 'early')
            u.where.append(f"{said}: its {', '.join(lags)} delays them more than the data do (standing in for "
                           "another effect?)")
        else:
            u.where.append(f"{said}: the steer is timed late (a command timed by its receive time, as a ROS Float64 "
                           "command without a header is: docs/ros.md; or a steer channel logged after the sensors), "
                           "or a sensor filter is declared slower than it is ([sensors])")
    # -- which band: the model's residual against the floor's, band by band
    for i, o in enumerate(OUTS):
        rows = []
        for lo, hi in BANDS_HZ:
            if lo >= fs / 2:
                continue
            m = np.sqrt(np.mean([_band_rms((p.y - p.yhat)[p.keep, i], fs, lo, hi) ** 2 for p in preds]))
            f = np.sqrt(np.mean([_band_rms(x, floor_rate(stretches), lo, hi) ** 2 for x in fe[o]])) if fe[o] else np.nan
            rows.append((f"{lo:g}-{min(hi, fs / 2):g} Hz", float(m), float(f)))
        u.by_band[o] = rows
        if o in short:
            excess = [(b, m * m - f * f) for b, m, f in rows if np.isfinite(f)]
            total = sum(max(x, 0) for _, x in excess)
            if total > 0:
                top = sorted(excess, key=lambda r: -r[1])[:2]
                u.where.append(f"{o}: the excess error lies at " + " and ".join(
                    f"{b} ({100 * max(x, 0) / total:.0f}%)" for b, x in top if x > 0))
    # -- which amplitude: residual rms per bin of |steer| and |ay| against the floor's
    steer = np.concatenate([st.steer[p.keep] for st, p in zip(stretches, preds)])
    ay = np.concatenate([p.y[p.keep, 0] for p in preds])
    y_all = np.vstack([p.y[p.keep] for p in preds])
    for what, x in (("|steer|", np.abs(steer)), ("|ay|", np.abs(ay))):
        edges = np.quantile(x, [0, 1 / 3, 2 / 3, 1])
        unit = "deg" if what == "|steer|" else "m/s^2"
        scale = np.degrees(1) if what == "|steer|" else 1.0
        labels = [f"{what} < {scale * edges[1]:.2g} {unit}", f"{scale * edges[1]:.2g}-{scale * edges[2]:.2g} {unit}",
                  f"> {scale * edges[2]:.2g} {unit}"]
        u.by_amplitude[what] = {}
        for i, o in enumerate(OUTS):
            rows = []
            for lab, a, b in zip(labels, edges[:-1], edges[1:]):
                m = (x >= a) & (x <= b)
                # the error relative to the output's own size in the bin: a linear miss scales
                # with the signal (constant ratio), a nonlinearity in amplitude does not
                rows.append((lab, float(np.sqrt(np.mean(e[m, i] ** 2))),
                             float(np.sqrt(np.mean((e[m, i] / max(np.sqrt(np.mean(y_all[m, i] ** 2)), 1e-12)) ** 2)))))
            u.by_amplitude[what][o] = rows
        for o in short:
            rows = u.by_amplitude[what][o]
            # middle third against the top third (the lowest holds mostly noise)
            if rows[2][2] > 1.5 * rows[1][2]:
                u.where.append(f"{o}: the error grows faster than the signal with {what}: {100 * rows[1][2]:.0f}% of "
                               f"{o} at {rows[1][0]}, {100 * rows[2][2]:.0f}% at {rows[2][0]}: a nonlinearity in "
                               "amplitude (a linear miss keeps the share constant)")
    # -- which speed: the model refitted at each speed on its own
    parts = parts or fit_groups(model_name, vehicle, stretches, result.all_params(), mapper)
    if "speed" in parts:
        groups = parts["speed"]
        u.by_speed = [(g.label, {n: (g.result.value(n), *dict(zip(g.result.names, g.result.ci95))[n])
                                 for n in g.result.names}) for g in groups]
        bad = [t for t in disagreements({"speed": groups}, result.names)]
        # (beyond their intervals by less than evidence.MATERIAL: no reason to refuse a name, but no
        # agreement either: a trial user's downforce moved Cf 15% from 4 to 6 m/s, dozens of interval
        # widths, and was told the fits agreed and the missing part does not change with speed)
        apart = [t for t in disagreements({"speed": groups}, result.names, material=0.0)] if not bad else []
        if bad:
            u.where.append("per-speed fits disagree: " + "; ".join(t for _, _, t in bad[:3])
                           + " (one car, so a parameter that moves with speed is another effect bending it)")
        elif apart:
            u.where.append("per-speed fits differ beyond their intervals, by under "
                           f"{100 * MATERIAL:.0f}%: " + "; ".join(t for _, _, t in apart[:3])
                           + " (the missing part may change with speed)")
        else:
            u.where.append("per-speed fits agree within their intervals ("
                           + ", ".join(g.label for g in groups) + "): the missing part does not change with speed")
        fit_by = ", ".join(f"{o} " + "/".join(f"{g.result.fit[o]:.1f}" for g in groups) + "%" for o in short)
        u.where.append(f"fit at {' / '.join(g.label for g in groups)}, each on its own: {fit_by}")
    else:
        u.where.append(one_speed_words(stretches))
    # -- what the residual follows
    reg = _regressors(stretches, preds)
    for o in short:
        r = e[:, OUTS.index(o)]
        tau = tau_int(r, max(2, int(0.5 * fs)))
        band = Z * np.sqrt(tau / len(r))
        rows = []
        for n, x in reg.items():
            if np.std(x) == 0:
                continue
            c = float(np.corrcoef(r, x)[0, 1])
            rows.append((n, c, band))
        # and |x| (a symmetric nonlinearity does not correlate with x itself)
        for n in ("steer", "ay"):
            x = np.abs(reg[n])
            rows.append((f"|{n}|", float(np.corrcoef(r, x)[0, 1]), band))
        rows.sort(key=lambda t: -abs(t[1]))
        u.follows[o] = rows
        hits = [t for t in rows if abs(t[1]) > t[2]]
        if hits:  # every channel it follows: the strongest three with their numbers first
            u.where.append(f"the {o} residual follows " + ", ".join(f"{n} (correlation {c:+.2f})" for n, c, _ in hits[:3])
                           + "".join(f", {n} ({c:+.2f})" for n, c, _ in hits[3:])
                           + f" (chance stays within +-{band:.2f})")
        else:
            u.where.append(f"the {o} residual follows none of {', '.join(reg)} beyond chance "
                           f"(+-{band:.2f}): look at its spectrum and at signals not logged")
    return u


# -- with no noise floor ---------------------------------------------------------------------

SHARE_GROWS = 1.5  # as above: the top third's error share against the middle third's


def where_without_floor(model_name, result, vehicle, stretches, mapper=map, parts=None) -> list:
    """Where the model misses when the data do not show what a correct model would reach
    (no noise floor: too little steering across frequencies). Nothing here can say the miss is
    more than noise; what it can say is measured against the signal itself: the band the error
    lies in and how much of the signal there it misses, whether its share grows with amplitude,
    whether fits per speed disagree, and which channels the residual follows beyond chance and
    by MIN_GAP fit points or more."""
    from stid.analysis.evidence import disagreements, fit_groups
    from stid.stats import tau_int

    preds, e = _residuals(result)
    if not len(e):
        return []
    fs = 1.0 / stretches[0].dt
    out = []
    for i, o in enumerate(OUTS):  # which band holds the error, and how much of the signal it misses there
        rows = []
        for lo, hi in BANDS_HZ:
            if lo >= fs / 2:
                continue
            err = np.sqrt(np.mean([_band_rms((p.y - p.yhat)[p.keep, i], fs, lo, hi) ** 2 for p in preds]))
            sig = np.sqrt(np.mean([_band_rms(p.y[p.keep, i], fs, lo, hi) ** 2 for p in preds]))
            rows.append((f"{lo:g}-{min(hi, fs / 2):g} Hz", float(err), float(sig)))
        total = sum(err ** 2 for _, err, _ in rows)
        if total > 0:
            top = sorted(rows, key=lambda r: -r[1])[:2]
            out.append(f"{o} (no floor to judge it by): its error lies at " + " and ".join(
                f"{b} ({100 * err ** 2 / total:.0f}%, {100 * err / max(sig, 1e-12):.0f}% of the signal there)"
                for b, err, sig in top))
    steer = np.concatenate([st.steer[p.keep] for st, p in zip(stretches, preds)])
    y = np.vstack([p.y[p.keep] for p in preds])
    for what, x in (("|steer|", np.abs(steer)), ("|ay|", np.abs(y[:, 0]))):
        edges = np.quantile(x, [1 / 3, 2 / 3])
        mid, top = (x >= edges[0]) & (x <= edges[1]), x > edges[1]
        if not (top.any() and mid.any()):  # a steer held at its clip a third of the time: no top third
            continue
        for i, o in enumerate(OUTS):
            share = [np.sqrt(np.mean(e[m, i] ** 2)) / max(np.sqrt(np.mean(y[m, i] ** 2)), 1e-12) for m in (mid, top)]
            if share[1] > SHARE_GROWS * share[0]:
                out.append(f"{o}: the error grows faster than the signal with {what} ({100 * share[0]:.0f}% of {o} "
                           f"in its middle third, {100 * share[1]:.0f}% in its top third): a nonlinearity in amplitude")
    parts = parts or fit_groups(model_name, vehicle, stretches, result.all_params(), mapper)
    if "speed" in parts:
        bad = disagreements({"speed": parts["speed"]}, result.names)
        if bad:
            out.append("per-speed fits disagree: " + "; ".join(t for _, _, t in bad[:3]))
    reg = _regressors(stretches, preds)
    for i, o in enumerate(OUTS):
        r = e[:, i]
        band = Z * np.sqrt(tau_int(r, max(2, int(0.5 * fs))) / len(r))
        # beyond chance is not enough without a floor: the part that follows a channel must be
        # worth MIN_GAP fit points (a 0.2% discretisation error at 50 Hz correlates +0.18 with
        # the steer rate over a minute of data)
        miss = np.linalg.norm(r) / max(np.linalg.norm(y[:, i] - y[:, i].mean()), 1e-12)
        hits = sorted(((n, float(np.corrcoef(r, x)[0, 1])) for n, x in reg.items() if np.std(x) > 0),
                      key=lambda t: -abs(t[1]))
        hits = [(n, c) for n, c in hits if abs(c) > band and 100 * miss * (1 - np.sqrt(1 - c * c)) >= MIN_GAP]
        if hits:
            out.append(f"the {o} residual follows " + ", ".join(f"{n} ({c:+.2f})" for n, c in hits[:4])
                       + f" (chance stays within +-{band:.2f})")
    return out
