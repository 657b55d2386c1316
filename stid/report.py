"""``stid report``: one self-contained HTML page (figures embedded) telling the
story of a data set: where the bicycle fails, which effects are missing, and the
error falling as they are added.

The numbers come from the diagnosis and fit objects; the functions named
``*_figure`` only draw them (python-control's habit: results hold numbers,
plot functions draw).
"""

from __future__ import annotations

import base64
import html
import io
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stid.analysis.noise_floor import below_floor  # noqa: E402
from stid.analysis.residuals import analyse  # noqa: E402
from stid.diagnose import diagnose  # noqa: E402
from stid.errors import InputError  # noqa: E402
from stid.output_paths import check_report_dir  # noqa: E402
from stid.stats import SCORE_FROM_S  # noqa: E402
from stid.fit.frf import estimate_frf  # noqa: E402
from stid.fit.result import at_resolution, se_text  # noqa: E402
from stid.fit.steady_fit import fit_steady  # noqa: E402
from stid.models.model import Model  # noqa: E402
from stid.present import diagnosis_text  # noqa: E402

# the first model amber (grey is the measurement's), the last red, those between in order
COLORS = ("#e69f00", "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#17becf", "#8c564b")


def _color(k: int, n: int) -> str:
    """The first model amber, the last red, those between in order."""
    if k == 0:
        return COLORS[0]
    if k == n - 1:
        return COLORS[2]
    return ((COLORS[1],) + COLORS[3:])[(k - 1) % (len(COLORS) - 2)]


def _legend_below(fig, axes, ncol=3):
    """One legend under the figure, never over the data."""
    handles, labels = [], []
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        # under the figure's bottom edge, below the axes' labels (the page's PNG is cut to
        # what is drawn, bbox_inches="tight", so it grows to hold it)
        fig.legend(handles, labels, loc="upper center", ncol=min(ncol, len(labels)), fontsize=8,
                   bbox_to_anchor=(0.5, 0.0), frameon=False)


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def chain_of(rounds) -> list:
    """(model name, fit result) along the chain bicycle -> +effect -> +effect. A pair named in
    one round is two links: its first effect alone (the fit that was bent), then both."""
    chain = [(rounds[0].model, rounds[0].base)]
    for d in rounds:
        if d.best is not None:
            chain.append((f"{d.model}+{d.best.effect}", d.best.result))
            if d.best.pair_with:
                chain.append((d.named_model, d.named_result))
    return chain


def error_fall_figure(chain, floor):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    labels = [name if k == 0 else "+" + name.split("+")[-1] for k, (name, _) in enumerate(chain)]
    x = np.arange(len(chain))
    for ax, out, title in zip(axes, ("ay", "r"), ("lateral acceleration ay", "yaw rate r")):
        vals = [res.fit[out] for _, res in chain]
        ax.plot(x, vals, "o-", color=COLORS[1], lw=2)
        for xi, v in zip(x, vals):  # (on a white patch: the floor's line may pass right under the label)
            ax.annotate(f"{v:.1f}%", (xi, v), textcoords="offset points", xytext=(0, 8), ha="center", zorder=4,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.9})
        if np.isfinite(floor[out]):
            ax.axhline(floor[out], color="k", ls="--", lw=1, label=f"noise floor {floor[out]:.1f}%")
            ax.set_title(f"{title} (floor {floor[out]:.1f}%, dashed)")
        else:  # (not determined by this data: see the diagnosis)
            ax.set_title(f"{title} (no noise floor on this data)")
        ax.set_xticks(x, labels, rotation=15)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fit [%]  100 (1 - |y - yhat| / |y - mean y|)")
    lo = max(min(min(min(res.fit.values()) for _, res in chain) - 5, 90), -50)
    axes[0].set_ylim(lo, 100 + 0.08 * (100 - lo))  # (room above 100% for the values written over the points)
    fig.suptitle("The error falls as the missing effects are added" if len(chain) > 1 else
                 f"The fit of {chain[0][0]} (the diagnosis named nothing to add)")
    fig.tight_layout(rect=(0, 0, 1, 0.93))  # (room for the title above the panels' own)
    return fig


def time_figure(chain, window_s=8.0):
    """Measured and every model of the chain, and below each output its residuals."""
    n = len(chain)
    fig, axes = plt.subplots(4, 1, figsize=(10, 8.5), sharex=True, gridspec_kw={"height_ratios": [2, 1, 2, 1]})
    p0 = chain[0][1].predictions[0]
    t = p0.t  # the run's own time, as in the overview and the exported CSV (the stretch starts later)
    m = (t >= t[0] + 2.0) & (t <= t[0] + 2.0 + window_s)
    for i, (lab, unit) in enumerate((("ay", "m/s^2"), ("r", "rad/s"))):
        ax, axr = axes[2 * i], axes[2 * i + 1]
        # the measurement as a broad band under the models' thin lines: a model that fits runs
        # inside it, and the band stays visible (drawn as a thin line, a good model hid it)
        ax.plot(t[m], p0.y[m, i], color="k", lw=4.0, alpha=0.25, solid_capstyle="butt", label="measured",
                zorder=1)
        for k, (name, res) in enumerate(chain):
            pk = res.predictions[0]
            ax.plot(t[m], pk.yhat[m, i], color=_color(k, n), lw=1.1, ls="-" if k == n - 1 else "--", label=name,
                    zorder=2 + k)
            axr.plot(t[m], (pk.y - pk.yhat)[m, i], color=_color(k, n), lw=0.9)
        ax.set_ylabel(f"{lab} [{unit}]")
        axr.set_ylabel(f"residual [{unit}]")
        axr.axhline(0, color="k", lw=0.5)
        for a_ in (ax, axr):
            a_.grid(alpha=0.3)
    axes[-1].set_xlabel(f"time in the run [s]  ({p0.name}, {p0.vx:.1f} m/s)")
    fig.suptitle("Measured and simulated with the measured steer, and what each model leaves (ISO 8855: left positive)")
    _legend_below(fig, axes, ncol=min(4, n + 1))
    fig.subplots_adjust(bottom=0.12)
    return fig


def overview_figure(runs):
    """What was logged: speed, steer, ay and r of every run, so the reader knows the data."""
    fig, axes = plt.subplots(4, 1, figsize=(10, 6.5), sharex=True)
    for k, run in enumerate(runs):
        col = COLORS[(k + 1) % len(COLORS)]
        t = run.t  # the run's own time, as the time figures (a piece a gap cut off starts at 0)
        for ax, y, lab in zip(axes, (run.vx, np.degrees(run.steer), run.ay, run.r),
                              ("vx [m/s]", "steer [deg]", "ay [m/s^2]", "r [rad/s]")):
            ax.plot(t, y, color=col, lw=0.7, label=run.name)
            ax.set_ylabel(lab)
            ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time in the run [s]")
    fig.suptitle("The logged runs (as loaded and calibrated, before any filtering)")
    _legend_below(fig, axes, ncol=2)
    fig.subplots_adjust(bottom=0.13)
    return fig


# A stretch whose speed spans more than this either side of its median: its measured response
# mixes speeds, and the model's, drawn at the median, is not what it should match.
SPEED_SPREAD = 0.1


def _speed_range(st):
    lo, hi = np.percentile(np.asarray(st.vx_series, float), [5, 95])
    return float(lo), float(hi)


def bode_figure(chain, stretches, vehicle):
    n = len(stretches)
    # the stretches nearest to one speed first: the model is drawn at each one's median speed
    shown = sorted(stretches, key=lambda st: (_speed_range(st)[1] - _speed_range(st)[0]) / max(st.vx, 1e-9))[:3]
    mixed = False
    fig, axes = plt.subplots(3, 2, figsize=(10, 7.5), sharex=True,
                             gridspec_kw={"height_ratios": [2, 2, 1]})
    for k, st in enumerate(shown):
        fr = estimate_frf(st)
        col = COLORS[(k + 1) % len(COLORS)]
        lo, hi = _speed_range(st)
        spread = max(hi - st.vx, st.vx - lo) > SPEED_SPREAD * st.vx
        mixed = mixed or spread
        label = (f"measured {lo:.1f}-{hi:.1f} m/s (models at {st.vx:.1f})" if spread else f"measured {st.vx:.1f} m/s")
        for j, out in enumerate(("ay/steer [(m/s^2)/rad]", "r/steer [1/s]")):
            axes[0, j].loglog(fr.f, np.abs(fr.H[j]), ".", color=col, ms=4, label=label)
            axes[1, j].semilogx(fr.f, np.degrees(np.unwrap(np.angle(fr.H[j]))), ".", color=col, ms=4)
            axes[2, j].semilogx(fr.f, fr.coh[j], color=col, lw=1)
            styles = (":", "-.", "--", "-")
            for m_i, (name, res) in enumerate(chain):
                ls = "-" if m_i == len(chain) - 1 else styles[m_i % 3]
                model = Model(name, vehicle)
                H = model.freqresp(res.all_params(), fr.f, st.vx, st.sensors)[j]
                axes[0, j].loglog(fr.f, np.abs(H), ls, color=col, lw=1.1,
                                  label=f"{name} ({ls})" if k == 0 and j == 0 else None)
                axes[1, j].semilogx(fr.f, np.degrees(np.unwrap(np.angle(H))), ls, color=col, lw=1.1)
            axes[0, j].set_title(out)
    axes[0, 0].set_ylabel("magnitude")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[2, 0].set_ylabel("coherence")
    for ax in axes[2]:
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylim(0, 1.05)
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    for ax in axes.ravel():
        ax.grid(alpha=0.3, which="both")
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
    for ax in axes[0]:
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    fig.suptitle("Frequency responses (H1, Welch) with coherence; one colour per stretch, one line style per "
                 "model" + ("" if n <= 3 else f" (3 of {n} stretches, the nearest to one speed)")
                 + ("\nwhere a stretch's speed varies, its measured response mixes speeds and the models' (at its "
                    "median speed) is not what it should match: the time plots judge the fit" if mixed else ""),
                 **({"fontsize": 10} if mixed else {}))
    _legend_below(fig, axes, ncol=3)
    fig.subplots_adjust(bottom=0.14)
    return fig


def residual_figure(chain, fs_raw: float, sensors: dict | None):
    """Residual autocorrelation against what a correct model leaves when the sensors' noise is
    white (that noise through the sensor's filter and the fit's prefilter: never white), and
    cross-correlation with the steer, each with its 99% band."""
    from stid.analysis.residuals import coloured_band, noise_autocorrelation

    fig, axes = plt.subplots(2, 2, figsize=(10, 6))
    for k, (name, res) in enumerate(chain):
        col = _color(k, len(chain))
        ra = analyse(res.predictions)
        L = len(ra.lags_s) // 2
        for j, out in enumerate(("ay", "r")):
            axes[0, j].plot(ra.lags_s[L:], ra.auto[out], color=col, label=name)
            axes[1, j].plot(ra.lags_s, ra.cross[out], color=col, label=name)
            axes[1, j].axhspan(-ra.cross_band[out], ra.cross_band[out], color=col, alpha=0.12)
            axes[0, j].set_title(f"autocorrelation of the {out} residual")
            axes[1, j].set_title(f"{out} residual vs steer (positive lag: residual after steer)")
    ra = analyse(chain[-1][1].predictions)
    L = len(ra.lags_s) // 2
    for j, out in enumerate(("ay", "r")):
        rho = noise_autocorrelation(fs_raw, float(ra.lags_s[L + 1] - ra.lags_s[L]), (sensors or {}).get(out) or 0.0,
                                    max_lag_s=float(ra.lags_s[-1]))[:L + 1]
        band = coloured_band(rho, ra.n)
        lags = ra.lags_s[L:]
        axes[0, j].plot(lags, rho, "k--", lw=1, label="white sensor noise through the sensor filter and prefilter")
        axes[0, j].fill_between(lags, rho - band, rho + band, color="k", alpha=0.1, lw=0)
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
        ax.set_xlabel("lag [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("correlation [-]")
    fig.suptitle("Residual analysis with 99% bands (shaded): a correct model's residual follows the dashed curve")
    fig.tight_layout(rect=(0, 0, 1, 0.95))  # (room for the title above the panels' own)
    _legend_below(fig, axes)
    return fig


RESIDUAL_WORDS = (
    "A correct model does not leave white residuals: the sensor's output filter and the fit's 20 Hz prefilter "
    "colour them. The dashed curve is that colour (white sensor noise through both), the grey band its 99% band; "
    "a residual above it at short lags holds colour the measurement chain does not explain (model error, or "
    "correlated sensor errors such as ADC steps or vibration). The cross-correlation bands allow for the colour "
    "of both signals.")


def residual_spectra(chain, stretches):
    """(f, {"floor" or model name: {output: PSD}}) of the noise floor's errors and every
    model's residuals, computed the same way: the same samples (each stretch thinned as the
    floor's predictor thins it, scored from the same instant), the same rate, one Welch
    estimate. A PSD's integral is its series' variance, so the floor's total is what a model
    at the floor leaves; its shape is the predictor's (see SPECTRUM_WORDS)."""
    from scipy import signal  # the report draws; its import time is not a command's

    from stid.analysis.noise_floor import floor_errors, floor_rate

    fl, _ = floor_errors(stretches)
    ffs = floor_rate(stretches)
    q = max(1, int(round(1.0 / (ffs * stretches[0].dt))))
    nper = int(4 * ffs)

    def psd(parts):
        x = np.concatenate(parts) if parts else np.zeros(0)
        if len(x) < nper:
            return None
        return signal.welch(x - x.mean(), fs=ffs, nperseg=nper)

    out, f = {}, None
    if all(fl[o] for o in ("ay", "r")):
        out["floor"] = {}
        for o in ("ay", "r"):
            f, out["floor"][o] = psd(fl[o])
    for name, res in chain:
        out[name] = {}
        for j, o in enumerate(("ay", "r")):
            parts = []
            for pr in res.predictions:
                e = (pr.y - pr.yhat)[::q, j]
                parts.append(e[pr.keep[::q] & ((pr.t[::q] - pr.t[0]) >= SCORE_FROM_S)])
            got = psd(parts)
            if got is not None:
                f, out[name][o] = got
    return f, out


SPECTRUM_WORDS = (
    "Every spectrum here is computed the same way, on the same samples: a model at the noise floor leaves the "
    "floor's total (the area under the black curve), but not necessarily its shape. The floor's predictor follows "
    "the car by a response of the steer alone; on runs whose speed varies it lies above a correct model in the "
    "steering band (where the steer has power) and below it elsewhere. Where a model's residual stands clearly "
    "above the floor, something the steer explains is still missing there.")


def spectrum_figure(chain, stretches):
    """Residual spectra of every model of the chain against the noise floor's predictor
    error, all from ``residual_spectra``."""
    f, spectra = residual_spectra(chain, stretches)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    f_max = 15.0
    band = f <= f_max if f is not None else None
    for j, (ax, out) in enumerate(zip(axes, ("ay", "r"))):
        shown = []  # the values inside the plotted band set the vertical range (the prefilter
        # takes the residual to nothing above 20 Hz, decades below anything of interest)
        if "floor" in spectra:  # (runs too short for the floor's predictor have none)
            ax.semilogy(f, spectra["floor"][out], color="k", lw=1.5, label="noise floor (its total: what a correct "
                                                                           "model leaves)")
            shown.append(spectra["floor"][out][band])
        for k, (name, _) in enumerate(chain):
            P = spectra[name].get(out)
            if P is not None:
                ax.semilogy(f, P, color=_color(k, len(chain)), lw=1.2, label=name)
                shown.append(P[band])
        ax.set_xlim(0, f_max)
        values = np.concatenate(shown) if shown else np.zeros(0)
        values = values[values > 0]
        if len(values):
            ax.set_ylim(0.3 * values.min(), 3.0 * values.max())
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(f"{out} residual spectrum [{'(m/s^2)^2/Hz' if out == 'ay' else '(rad/s)^2/Hz'}]")
        ax.grid(alpha=0.3, which="both")
    fig.suptitle("Residual spectra against the noise floor")
    fig.tight_layout()
    _legend_below(fig, axes)
    return fig


def ay_bins(predictions, edges=(0.0, 2.0, 4.0, 6.0, np.inf)) -> list:
    """Per |ay| bin of the measured ay: (label, samples, residual rms [m/s^2], the residual's
    mean in the direction of ay [m/s^2]). A friction limit the model lacks makes it overshoot
    where |ay| is large: a systematic residual against ay there (negative). A lag grows the rms
    with the amplitude too, but the model then falls short at the peaks (positive)."""
    y = np.concatenate([p.y[p.keep, 0] for p in predictions])
    e = np.concatenate([(p.y - p.yhat)[p.keep, 0] for p in predictions])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (np.abs(y) >= lo) & (np.abs(y) < hi)
        if m.sum() < 50:
            continue
        label = f"{lo:g}-{hi:g}" if np.isfinite(hi) else f"> {lo:g}"
        out.append((label, int(m.sum()), float(np.sqrt(np.mean(e[m] ** 2))), float(np.mean(e[m] * np.sign(y[m])))))
    return out


def by_ay_figure(chain):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    rows = [ay_bins(res.predictions) for _, res in chain]
    bins = [r[0] for r in rows[0]]
    x = np.arange(len(bins))
    w = 0.8 / len(chain)
    for k, ((name, _), rs) in enumerate(zip(chain, rows)):
        col = _color(k, len(chain))
        got = {r[0]: r for r in rs}
        axes[0].bar(x - 0.4 + (k + 0.5) * w, [got[b][2] if b in got else np.nan for b in bins], w, color=col,
                    label=name)
        axes[1].bar(x - 0.4 + (k + 0.5) * w, [got[b][3] if b in got else np.nan for b in bins], w, color=col)
    for ax in axes:
        ax.set_xticks(x, [f"|ay| {b} m/s^2" for b in bins], rotation=10, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("ay residual rms [m/s^2]")
    axes[0].set_title("how large the error is, per |ay|")
    axes[1].axhline(0, color="k", lw=0.6)
    axes[1].set_ylabel("mean of residual x sign(ay) [m/s^2]")
    axes[1].set_title("its systematic part (< 0: overshoots, as at a friction limit)")
    fig.suptitle("Where the error lives across |ay|: a friction limit shows as a systematic overshoot at large |ay|")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    _legend_below(fig, axes)
    return fig


def unexplained_figure(u):
    """Where the last model still fails against the floor: per band, per amplitude, and
    what its residual follows (the same numbers as the text's 'unexplained')."""
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
    outs = ("ay", "r")
    for j, o in enumerate(outs):
        rows = u.by_band.get(o, [])
        x = np.arange(len(rows))
        axes[0].bar(x + (j - 0.5) * 0.4, [r[1] / r[2] if r[2] > 0 else np.nan for r in rows], 0.4,
                    color=COLORS[1 + 2 * j], label=o)
        axes[0].set_xticks(x, [r[0] for r in rows], rotation=15, fontsize=8)
    axes[0].axhline(1.0, color="k", lw=1, ls="--")
    axes[0].set_title("residual rms / floor's, per band")
    for j, o in enumerate(outs):
        rows = u.by_amplitude.get("|steer|", {}).get(o, [])
        if rows:
            axes[1].plot([r[0] for r in rows], [100 * r[2] for r in rows], "o-", color=COLORS[1 + 2 * j], label=o)
    axes[1].set_title("residual rms / output rms per |steer| third [%]")
    axes[1].tick_params(axis="x", labelsize=8)
    names, vals, cols = [], [], []
    for j, o in enumerate(outs):
        for n, c, band in u.follows.get(o, [])[:4]:
            names.append(f"{o}: {n}")
            vals.append(c)
            cols.append(COLORS[1 + 2 * j] if abs(c) > band else "#cccccc")
    axes[2].barh(np.arange(len(vals)), vals, color=cols)
    axes[2].set_yticks(np.arange(len(vals)), names, fontsize=8)
    axes[2].axvline(0, color="k", lw=0.5)
    axes[2].set_title("what the residual follows (grey: chance)")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"Where {u.model} still fails")
    fig.tight_layout()
    _legend_below(fig, axes[:2], ncol=2)
    return fig


def steady_figure(runs, vehicle):
    from stid.fit.dataset import steady_points

    pts = steady_points(runs)
    if len(pts.ay) < 5 or np.ptp(pts.ay) < 1.0:
        return None, None
    res = fit_steady(Model("bicycle", vehicle), pts)
    ncol = 2 if pts.beta is not None else 1
    fig, axes = plt.subplots(1, ncol, figsize=(5 * ncol, 3.6), squeeze=False)
    inv_R = pts.r / pts.vx
    a = np.linspace(pts.ay.min(), pts.ay.max(), 50)
    ax = axes[0, 0]
    ax.plot(pts.ay, np.degrees(pts.steer - vehicle.L * inv_R), ".", label="measured")
    ax.plot(a, np.degrees(res.extra["eta"] * a + res.extra["delta0"]), "-", label="fit")
    ax.set_xlabel("ay [m/s^2]")
    ax.set_ylabel("delta - L/R [deg]")
    ax.set_title(f"steer: understeer gradient {np.degrees(res.extra['eta']) * 9.81:.2f} deg/g")
    if pts.beta is not None:
        ax = axes[0, 1]
        ax.plot(pts.ay, np.degrees(pts.beta - vehicle.b * inv_R), ".")
        ax.plot(a, np.degrees(res.extra["k_beta"] * a + res.extra["beta0"]), "-")
        ax.set_xlabel("ay [m/s^2]")
        ax.set_ylabel("beta - b/R [deg]")
        ax.set_title("body slip")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.suptitle("Steady-state cornering")
    return fig, res


def _figure(title: str, fig, words: str = "") -> str:
    """A figure with its heading (and what it shows, in words), kept together in print."""
    return (f"<figure><h2>{html.escape(title)}</h2><img src='data:image/png;base64,{_png(fig)}'>"
            + (f"<figcaption class='note'>{html.escape(words)}</figcaption>" if words else "") + "</figure>")


def _params_table(res) -> str:
    rows = []
    for n, v, se, (lo, hi) in zip(res.names, res.values, res.stderr, res.ci95):
        ci = (f"[{at_resolution(lo, se)}, {at_resolution(hi, se)}]" if res.interval_of(n)
              else f"no interval ({html.escape(res.undetermined.get(n, ''))})")
        rows.append(f"<tr><td>{n}</td><td>{at_resolution(v, se)}</td><td>{se_text(se)}</td><td>{ci}</td>"
                    f"<td>{html.escape(res.units[n])}</td><td>{html.escape(res.owners.get(n, ''))}</td></tr>")
    for n, (v, unit, why) in res.fixed.items():
        rows.append(f"<tr><td>{n}</td><td>{v:.5g}</td><td>fixed</td><td></td><td>{html.escape(unit)}</td>"
                    f"<td>{html.escape(why)}</td></tr>")
    return ("<table><tr><th>parameter</th><th>value</th><th>std. error</th><th>95% interval</th><th>unit</th>"
            "<th>from</th></tr>" + "".join(rows) + "</table>"
            + (f"<p class='warn'>{html.escape(res.verdict_line())}</p>" if res.verdict_line() else "")
            + (f"<p class='note'>{html.escape(res.interval)}</p>" if res.interval and res.converged else ""))


def write_report(runs, vehicle, out_dir, model_name: str = "bicycle", progress=None, rounds=None,
                 run_paths=None, vehicle_path=None, overwrite: bool = False) -> Path:
    """The page for ``runs``; ``rounds``: a ``diagnose(..., peel=True)`` already made of them.
    ``run_paths``, ``vehicle_path``: the files as the user named them, for the command the
    page says to run next (default: the runs' names and the vehicle file's path)."""
    out_dir = check_report_dir(out_dir, overwrite)
    try:  # before the diagnosis: a directory that cannot be made is known in a millisecond
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot make the report directory {out_dir} ({e.strerror or e}): "
                         "give one that can be written with -o") from None
    rounds = rounds or diagnose(runs, vehicle, model_name, peel=True, progress=progress)
    chain = chain_of(rounds)
    stretches = rounds[-1].stretches  # the data every fit of the diagnosis used
    floor = rounds[0].floor
    if progress:
        progress.step("drawing figures")
    figs = [("Measured vs model in time", time_figure(chain), ""),
            ("Measured vs model in frequency", bode_figure(chain, stretches, vehicle), ""),
            ("Where the error lives across |ay|", by_ay_figure(chain), ""),
            ("Residual analysis", residual_figure(chain, runs[0].fs, stretches[0].sensors), RESIDUAL_WORDS),
            ("Residual spectra against the noise floor", spectrum_figure(chain, stretches), SPECTRUM_WORDS)]
    u = rounds[-1].unexplained
    if u is not None and u.by_band:
        figs.append((f"Where {u.model} still fails", unexplained_figure(u), ""))
    sfig, sres = steady_figure(runs, vehicle)
    if sfig is not None:
        figs.insert(2, ("Steady-state cornering", sfig, ""))
    found = [name.split("+")[-1] for name, _ in chain[1:]]
    last_name, last = chain[-1]
    story = (f"The bicycle model alone fits ay {chain[0][1].fit['ay']:.1f}%, r {chain[0][1].fit['r']:.1f}%. "
             + (f"The diagnosis found {', '.join(found)}; with {'it' if len(found) == 1 else 'them'} added "
                f"({last_name}) the fit is ay {last.fit['ay']:.1f}%, r {last.fit['r']:.1f}%. " if found else
                "The diagnosis names no missing effect. ")
             + "The noise floor (what a correct model reaches on this data) is "
             + ", ".join(f"{o} {floor[o]:.1f}%" if np.isfinite(floor[o]) else f"{o} not determined" for o in ("ay", "r"))
             + (". " if all(np.isfinite(floor[o]) for o in ("ay", "r")) else
                f": without it, nothing here says how far {last_name} is from a correct model"
                + (", and no effect named is not a model found complete. " if not found else ". "))
             + "The whole diagnosis, in words, is at the end of the page.")
    parts = [f"<h1>stid report: {html.escape(vehicle.name)}</h1>",
             f"<p>{len(runs)} run(s): {html.escape(', '.join(r.name for r in runs))}. "
             f"Generated {time.strftime('%Y-%m-%d %H:%M')}. Units SI, ISO 8855 axes (x forward, y left, z up), "
             "cornering stiffness per axle in N/rad.</p>",
             f"<p class='story'>{html.escape(story)}</p>",
             _figure("The error falls" if len(chain) > 1 else "The fit", error_fall_figure(chain, floor)),
             _figure("The logged runs", overview_figure(runs)),
             "<h2>Along the chain</h2>"]
    for k, (name, res) in enumerate(chain):
        parts.append(f"<section class='keep'><h3>{html.escape(name)}: fit ay {res.fit['ay']:.1f}%, "
                     f"r {res.fit['r']:.1f}%</h3>" + _params_table(res))
        short = below_floor(res, floor, rounds[0].floor_se)
        if short:
            parts.append("<p class='warn'>" + html.escape(
                f"{name} is {', '.join(f'{o} {g:.1f}' for o, g in short.items())} points below the noise floor: "
                "its intervals hold only if it were right (a model that misses an effect bends its parameters "
                "to make up for it, by more than the intervals show)"
                + ("; the next model's are the ones to read" if k < len(chain) - 1 else
                   "; where it still fails is shown below"))
                + "</p>")
        for w in res.warnings:
            parts.append(f"<p class='warn'>warning: {html.escape(w)}</p>")
        parts.append("</section>")
    if sres is not None:
        parts.append("<section class='keep'><h3>steady state</h3>" + _params_table(sres) + "</section>")
        for w in sres.warnings:
            parts.append(f"<p class='warn'>note: {html.escape(w)}</p>")
    for title, fig, words in figs:
        parts.append(_figure(title, fig, words))
    parts.append("<h2>The diagnosis in words</h2><pre>" + html.escape(diagnosis_text(
        rounds, run_paths or [r.name for r in runs], vehicle_path or vehicle.path or vehicle.name,
        peel=True)) + "</pre>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
             "text-align:right}pre{background:#f6f6f6;padding:1em;white-space:pre-wrap;overflow-wrap:anywhere;"
             "font-size:12px}img{max-width:100%}.warn{color:#a60}.note{color:#555;font-size:90%}"
             ".story{font-size:110%;line-height:1.45}"
             # print: a heading stays with what it heads, a figure or a table is not cut in two
             "h1,h2,h3{break-after:avoid;page-break-after:avoid}"
             "figure,.keep,img,table{break-inside:avoid;page-break-inside:avoid}figure{margin:0}")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>stid report</title><style>{style}</style>"
            f"</head><body>{''.join(parts)}</body></html>")
    path = out_dir / "report.html"
    path.write_text(page)
    return path
