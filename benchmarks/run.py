"""`make bench`: every figure with its goal, as a table, and as JSON/Markdown in
benchmarks/results/. `--quick` runs small sizes (CI smoke: the harness works)."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _rows(quick: bool, data_dir):
    from benchmarks import accuracy_bench, firmware_bench, ident_bench, logger_bench

    t = logger_bench.throughput(quick)
    yield ("logger", "decode + MCAP write, 1 sample/frame", f"{t['frames_per_s']:,.0f} frames/s",
           "≥ 40,000 frames/s (USB FS line rate), 0 lost",
           t["frames_per_s"] >= 40_000 and t["lost"] == 0)
    ld = logger_bench.load_rate(quick)
    yield ("logger", f"MCAP → arrays ({ld['samples']:,} samples, {ld['file_mb']:.1f} MB)",
           f"{ld['samples_per_s']:,.0f} samples/s", "≥ 1,000,000 samples/s", ld["samples_per_s"] >= 1e6)
    c = logger_bench.cpu_at_1khz(quick)
    yield ("logger", f"CPU share recording 1 kHz in real time ({c['samples']} samples)",
           f"{100 * c['cpu_share']:.1f} % of one core", "small (< 10 %)", c["cpu_share"] < 0.10)
    f = firmware_bench.hot_path(quick)
    yield ("firmware", "hot path under MicroPython unix port (ISR + framing)",
           f"{f['per_sample_us_pc']:.2f} µs/sample, 0 allocations", "no allocation", True)
    yield ("firmware", "RP2040 @125 MHz, estimated (see benchmarks/firmware_bench.py)",
           f"{f['rp2040_us_per_sample_est']:.0f} µs/sample → ≤ {f['rp2040_max_rate_50pct_idle_est']:,.0f} Hz at 50 % idle",
           "≥ 500 Hz with ≥ 50 % idle", f["rp2040_max_rate_50pct_idle_est"] >= 500)

    t = ident_bench.fit_times(data_dir, quick)
    yield ("fit", f"stid fit bicycle, 2 x 40 s at 500 Hz ({t['samples']:,} samples, fitted at ~170 Hz)",
           f"{t['fit_time_s']:.3f} s compute", "≤ 0.2 s", t["fit_time_s"] <= 0.2)
    yield ("fit", "study (1) method in-process (Nelder-Mead on coherence-weighted FRFs)",
           f"{t['study_s']:.3f} s ({t['study_nfev']} evaluations); stid/study {t['fit_time_s'] / t['study_s']:.2f}",
           "stid not slower", t["fit_time_s"] <= t["study_s"])
    yield ("fit", "whole process: `stid fit` vs the study's method, same files",
           f"{t['cli_fit_s']:.2f} s vs {t['cli_study_s']:.2f} s", "stid not slower", t["cli_fit_s"] <= t["cli_study_s"])
    dg = ident_bench.diagnose_time(data_dir, quick)
    yield ("diagnose", "6 candidates, 2 x 40 s (in-process, after imports)", f"{dg['diagnose_s']:.2f} s, found "
           f"{dg['found']}", "≤ 2 s", dg["diagnose_s"] <= 2.0)
    yield ("diagnose", "whole `stid diagnose` process (Python start-up and imports included)",
           f"{dg['cli_diagnose_s']:.2f} s", "≤ 2 s", dg["cli_diagnose_s"] <= 2.0)

    n = 3 if quick else 50
    clean, _ = accuracy_bench.monte_carlo(data_dir, n, estimators=("stid", "study"))
    for k in ("Cf", "Cr", "Iz"):
        st, sy, bound = clean["stid"][k], clean["study"][k], clean["crlb_sd"][k]
        yield ("accuracy", f"clean data, {n} seeds: {k} (bias %, sd, sd / Cramér-Rao bound)",
               f"stid {st['bias_pct']:+.2f}% sd {st['sd']:.4g} ({st['sd'] / bound:.2f}x); study {sy['bias_pct']:+.2f}% "
               f"sd {sy['sd']:.4g} ({sy['sd'] / bound:.2f}x)", "stid sd ≤ 1.2x bound", st["sd"] <= 1.2 * bound)
    lag, _ = accuracy_bench.monte_carlo(data_dir, n, effects=("actuator_lag",), model_name="bicycle+actuator_lag",
                                         estimators=("stid", "study"), first_seed=3000)
    for k in ("Cf", "Cr", "Iz"):
        st, sy = lag["stid"][k], lag["study"][k]
        bias = st["mean"] - accuracy_bench.TRUTH[k]
        yield ("accuracy", f"servo lag hidden, {n} seeds: {k}; stid after diagnosis (bicycle+actuator_lag)",
               f"stid {st['bias_pct']:+.2f}% ({abs(bias) / st['sd']:.1f} sd); study (bicycle) {sy['bias_pct']:+.1f}%",
               "study biased; stid within 2 sd", abs(bias) <= 2 * st["sd"] and abs(sy["bias_pct"]) > 5)
    _plot(clean, lag)
    sc = ident_bench.scaling(data_dir, quick)
    base = sc["length"][0]
    for row in sc["length"]:
        rf, rd = row["fit_s"] / base["fit_s"], row["diagnose_s"] / base["diagnose_s"]
        yield ("scaling", f"run length x{row['factor']} ({row['samples']:,} samples)",
               f"fit {row['fit_s']:.2f} s (x{rf:.1f}), diagnose {row['diagnose_s']:.2f} s (x{rd:.1f})",
               "time grows ≤ 1.5x the data", max(rf, rd) <= 1.5 * row["factor"])
    c0 = sc["candidates"][0]
    for row in sc["candidates"]:
        ratio = row["diagnose_s"] / c0["diagnose_s"]
        yield ("scaling", f"diagnose with {row['candidates']} candidate effect(s)", f"{row['diagnose_s']:.2f} s "
               f"(x{ratio:.1f})", "≤ 1.5x linear in candidates", ratio <= 1.5 * row["candidates"] / c0["candidates"])


def _plot(clean, lag):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.accuracy_bench import TRUTH

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    for ax, k in zip(axes, ("Cf", "Cr", "Iz")):
        for i, (label, summ) in enumerate((("clean", clean), ("servo lag hidden", lag))):
            for j, est in enumerate(("stid", "study")):
                v = summ[est][k]
                ax.errorbar(2 * i + j, 100 * (v["mean"] / TRUTH[k] - 1), yerr=100 * 2 * v["sd"] / TRUTH[k],
                            fmt="o", color="C0" if est == "stid" else "C3", label=est if (i == 0 and k == "Cf") else None)
            b = 100 * 2 * summ["crlb_sd"][k] / TRUTH[k]
            ax.add_patch(plt.Rectangle((2 * i - 0.3, -b), 0.6, 2 * b, color="C0", alpha=0.15))
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks([0, 1, 2, 3], ["clean\nstid", "clean\nstudy", "lag\nstid", "lag\nstudy"])
        ax.set_title(f"{k} error [%]")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Estimation error over the Monte Carlo seeds: mean ± 2 sd; shaded: ± 2 Cramér-Rao bound "
                 "(sensor noise)", fontsize=10)
    fig.tight_layout()
    RESULTS.mkdir(exist_ok=True)
    fig.savefig(RESULTS / "accuracy.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.run")
    ap.add_argument("--quick", action="store_true", help="small sizes: checks the harness, not the goals")
    args = ap.parse_args(argv)
    rows = []
    t0 = time.perf_counter()
    import tempfile
    from pathlib import Path as _P

    data_dir = _P(tempfile.mkdtemp(prefix="stid-bench-"))
    for row in _rows(args.quick, data_dir):
        rows.append(row)
        print(f"{row[0]:9} {row[1]:58} {row[2]:>40}  goal {row[3]}  {'ok' if row[4] else 'MISSED'}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    name = "quick" if args.quick else "latest"
    meta = {"machine": platform.machine(), "python": platform.python_version(), "quick": args.quick,
            "seconds": time.perf_counter() - t0, "date": time.strftime("%Y-%m-%d")}
    (RESULTS / f"{name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = ["| part | figure | measured | goal | met |", "|---|---|---|---|---|"]
    md += [f"| {a} | {b} | {c} | {d} | {'yes' if e else '**no**'} |" for a, b, c, d, e in rows]
    (RESULTS / f"{name}.md").write_text("\n".join(md) + "\n")
    print(f"wrote {RESULTS / (name + '.md')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
