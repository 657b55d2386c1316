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

from stid.analysis.compare import breakdown  # noqa: E402
from stid.analysis.residuals import analyse  # noqa: E402
from stid.diagnose import diagnose  # noqa: E402
from stid.fit import dataset  # noqa: E402
from stid.fit.frf import estimate_frf  # noqa: E402
from stid.fit.steady_fit import fit_steady  # noqa: E402
from stid.models.model import Model  # noqa: E402
from stid.present import diagnosis_text  # noqa: E402

COLORS = ("#888888", "#1f77b4", "#d62728", "#2ca02c", "#9467bd")


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def chain_of(rounds) -> list:
    """(model name, fit result) along the chain bicycle -> +effect -> +effect."""
    chain = [(rounds[0].model, rounds[0].base)]
    for d in rounds:
        if d.best is not None:
            chain.append((f"{d.model}+{d.best.effect}", d.best.result))
    return chain


def error_fall_figure(chain, floor):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    labels = [name if k == 0 else "+" + name.split("+")[-1] for k, (name, _) in enumerate(chain)]
    x = np.arange(len(chain))
    for ax, out, title in zip(axes, ("ay", "r"), ("lateral acceleration ay", "yaw rate r")):
        vals = [res.fit[out] for _, res in chain]
        ax.plot(x, vals, "o-", color=COLORS[1], lw=2)
        for xi, v in zip(x, vals):
            ax.annotate(f"{v:.1f}%", (xi, v), textcoords="offset points", xytext=(0, 8), ha="center")
        ax.axhline(floor[out], color="k", ls="--", lw=1, label=f"noise floor {floor[out]:.1f}%")
        ax.set_xticks(x, labels, rotation=15)
        ax.set_title(title)
        ax.legend(loc="lower right")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fit [%]  100 (1 - |y - yhat| / |y - mean y|)")
    lo = min(min(res.fit.values()) for _, res in chain)
    axes[0].set_ylim(max(min(lo - 5, 90), -50), 101)
    fig.suptitle("The error falls as the missing effects are added")
    return fig


def time_figure(chain, window_s=8.0):
    first, last = chain[0][1], chain[-1][1]
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.2), sharex=True)
    p0 = first.predictions[0]
    pl = last.predictions[0]
    t = p0.t - p0.t[0]
    m = (t >= 2.0) & (t <= 2.0 + window_s)
    for i, (ax, lab) in enumerate(zip(axes, ("ay [m/s^2]", "r [rad/s]"))):
        ax.plot(t[m], p0.y[m, i], color="k", lw=1.2, label="measured")
        ax.plot(t[m], p0.yhat[m, i], color=COLORS[0], lw=1.2, label=chain[0][0])
        ax.plot(t[m], pl.yhat[m, i], color=COLORS[2], lw=1.2, ls="--", label=chain[-1][0])
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel(f"time [s]  ({p0.name}, {p0.vx:.1f} m/s)")
    fig.suptitle("Measured and simulated with the measured steer (ISO 8855: left positive)")
    return fig


def bode_figure(chain, stretches, vehicle):
    n = len(stretches)
    fig, axes = plt.subplots(3, 2, figsize=(10, 7.5), sharex=True,
                             gridspec_kw={"height_ratios": [2, 2, 1]})
    for k, st in enumerate(stretches[:3]):
        fr = estimate_frf(st)
        col = COLORS[(k + 1) % len(COLORS)]
        for j, out in enumerate(("ay/steer [(m/s^2)/rad]", "r/steer [1/s]")):
            axes[0, j].loglog(fr.f, np.abs(fr.H[j]), ".", color=col, ms=4, label=f"measured {st.vx:.1f} m/s")
            axes[1, j].semilogx(fr.f, np.degrees(np.unwrap(np.angle(fr.H[j]))), ".", color=col, ms=4)
            axes[2, j].semilogx(fr.f, fr.coh[j], color=col, lw=1)
            for (name, res), ls in zip((chain[0], chain[-1]), (":", "-")):
                model = Model(name, vehicle)
                H = model.freqresp(res.all_params(), fr.f, st.vx, st.sensors)[j]
                axes[0, j].loglog(fr.f, np.abs(H), ls, color=col, lw=1.2,
                                  label=name if k == 0 else None)
                axes[1, j].semilogx(fr.f, np.degrees(np.unwrap(np.angle(H))), ls, color=col, lw=1.2)
            axes[0, j].set_title(out)
    axes[0, 0].legend(fontsize=7)
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
    fig.suptitle(f"Frequency responses (H1, Welch) with coherence; dotted {chain[0][0]}, solid {chain[-1][0]}"
                 + ("" if n <= 3 else f" (first 3 of {n} stretches)"))
    return fig


def residual_figure(chain):
    fig, axes = plt.subplots(2, 2, figsize=(10, 5.5))
    for (name, res), col in zip((chain[0], chain[-1]), (COLORS[0], COLORS[2])):
        ra = analyse(res.predictions)
        L = len(ra.lags_s) // 2
        for j, out in enumerate(("ay", "r")):
            axes[0, j].plot(ra.lags_s[L:], ra.auto[out], color=col, label=name)
            axes[1, j].plot(ra.lags_s, ra.cross[out], color=col, label=name)
            axes[0, j].axhspan(-ra.band, ra.band, color="k", alpha=0.1)
            axes[1, j].axhspan(-ra.cross_band[out], ra.cross_band[out], color=col, alpha=0.12)
            axes[0, j].set_title(f"autocorrelation of the {out} residual")
            axes[1, j].set_title(f"{out} residual vs steer (positive lag: residual after steer)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
        ax.set_xlabel("lag [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Residual analysis with 99% bands (shaded; cross-correlation bands allow for coloured signals)")
    fig.tight_layout()
    return fig


def spectrum_figure(chain, stretches):
    """Residual spectra of the first and last model against the noise floor's (the FIR
    predictor's cross-validated error): where a model's residual sits above the floor,
    something the steer explains is still missing there."""
    from scipy import signal

    from stid.analysis.noise_floor import floor_errors

    fl, _ = floor_errors(stretches)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    fs = 1.0 / stretches[0].dt
    nper = int(4 * fs)
    for j, (ax, out) in enumerate(zip(axes, ("ay", "r"))):
        f, P = signal.welch(np.concatenate(fl[out]), fs=fs, nperseg=nper)
        ax.semilogy(f, P, color="k", lw=1.5, label="noise floor (best linear predictor)")
        for (name, res), col in zip((chain[0], chain[-1]), (COLORS[0], COLORS[2])):
            e = np.concatenate([(p.y - p.yhat)[p.keep, j] for p in res.predictions])
            f2, Pe = signal.welch(e - e.mean(), fs=fs, nperseg=nper)
            ax.semilogy(f2, Pe, color=col, lw=1.2, label=name)
        ax.set_xlim(0, 15)
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(f"{out} residual spectrum [{'(m/s^2)^2/Hz' if out == 'ay' else '(rad/s)^2/Hz'}]")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.suptitle("Residual spectra against the noise floor")
    fig.tight_layout()
    return fig


def by_ay_figure(chain):
    fig, ax = plt.subplots(figsize=(7, 3.4))
    first, last = chain[0][1], chain[-1][1]
    bd0, bd1 = breakdown(first.predictions), breakdown(last.predictions)
    bins = list(bd0.by_ay)
    x = np.arange(len(bins))
    ax.bar(x - 0.2, [bd0.by_ay[b]["ay"] for b in bins], 0.4, color=COLORS[0], label=chain[0][0])
    ax.bar(x + 0.2, [bd1.by_ay[b]["ay"] for b in bins], 0.4, color=COLORS[2], label=chain[-1][0])
    ax.set_xticks(x, bins, rotation=10)
    ax.set_ylabel("ay fit in the bin [%]")
    ax.set_title("Where the error lives: linear range vs the friction limit")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
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


def _params_table(res) -> str:
    rows = []
    for n, v, se in zip(res.names, res.values, res.stderr):
        rows.append(f"<tr><td>{n}</td><td>{v:.5g}</td><td>{se:.3g}</td><td>{html.escape(res.units[n])}</td>"
                    f"<td>{html.escape(res.owners.get(n, ''))}</td></tr>")
    for n, (v, unit, why) in res.fixed.items():
        rows.append(f"<tr><td>{n}</td><td>{v:.5g}</td><td>fixed</td><td>{html.escape(unit)}</td>"
                    f"<td>{html.escape(why)}</td></tr>")
    return ("<table><tr><th>parameter</th><th>value</th><th>std. error</th><th>unit</th><th>from</th></tr>"
            + "".join(rows) + "</table>")


def write_report(runs, vehicle, out_dir, model_name: str = "bicycle", progress=None) -> Path:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rounds = diagnose(runs, vehicle, model_name, peel=True, progress=progress)
    chain = chain_of(rounds)
    stretches = dataset.dynamic_stretches(runs, target_fs=50.0)
    floor = rounds[0].floor
    if progress:
        progress.step("drawing figures")
    figs = [("The error falls", error_fall_figure(chain, floor)),
            ("Measured vs model in time", time_figure(chain)),
            ("Measured vs model in frequency", bode_figure(chain, stretches, vehicle)),
            ("Where the error lives", by_ay_figure(chain)),
            ("Residual analysis", residual_figure(chain)),
            ("Residual spectra against the noise floor", spectrum_figure(chain, stretches))]
    sfig, sres = steady_figure(runs, vehicle)
    if sfig is not None:
        figs.insert(3, ("Steady-state cornering", sfig))
    parts = [f"<h1>stid report: {html.escape(vehicle.name)}</h1>",
             f"<p>{len(runs)} run(s): {html.escape(', '.join(r.name for r in runs))}. "
             f"Generated {time.strftime('%Y-%m-%d %H:%M')}. Units SI, ISO 8855 axes (x forward, y left, z up), "
             "cornering stiffness per axle in N/rad.</p>",
             "<h2>Diagnosis</h2><pre>" + html.escape(diagnosis_text(rounds)) + "</pre>",
             "<h2>Along the chain</h2>"]
    for name, res in chain:
        parts.append(f"<h3>{html.escape(name)}: fit ay {res.fit['ay']:.1f}%, r {res.fit['r']:.1f}%</h3>")
        parts.append(_params_table(res))
        for w in res.warnings:
            parts.append(f"<p class='warn'>warning: {html.escape(w)}</p>")
    if sres is not None:
        parts.append("<h3>steady state</h3>" + _params_table(sres))
        for w in sres.warnings:
            parts.append(f"<p class='warn'>note: {html.escape(w)}</p>")
    for title, fig in figs:
        parts.append(f"<h2>{html.escape(title)}</h2><img src='data:image/png;base64,{_png(fig)}'>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
             "text-align:right}pre{background:#f6f6f6;padding:1em;overflow-x:auto;font-size:12px}"
             "img{max-width:100%}.warn{color:#a60}")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>stid report</title><style>{style}</style>"
            f"</head><body>{''.join(parts)}</body></html>")
    path = out_dir / "report.html"
    path.write_text(page)
    return path
