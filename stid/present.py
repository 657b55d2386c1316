"""Human-readable text for diagnose and compare results (the numbers live in the
result objects; this only lays them out)."""

from __future__ import annotations

import numpy as np


def _pct(x) -> str:
    return f"{x:5.1f}%" if np.isfinite(x) else "   - "


def diagnosis_text(rounds, vehicle_name: str = "") -> str:
    lines = []
    for k, d in enumerate(rounds):
        speeds = sorted({round(p.vx, 1) for p in d.base.predictions})
        head = "" if k == 0 else f"step {k + 1}: "
        lines.append(f"{head}model {d.model}: fit ay {d.base.fit['ay']:.1f}%, r {d.base.fit['r']:.1f}%   "
                     f"noise floor ay {d.floor['ay']:.1f}%, r {d.floor['r']:.1f}%   "
                     f"({len(d.base.predictions)} stretches at {', '.join(f'{v:g}' for v in speeds)} m/s)")
        lines.append(f"  {'candidate':<18}{'fit ay':>8}{'fit r':>8}{'LR':>9}{'p':>10}   verdict")
        for c in d.candidates:
            if c.skipped:
                lines.append(f"  {c.effect:<18}{'':>8}{'':>8}{'':>9}{'':>10}   not tested: {c.skipped}")
                continue
            verdict = "SIGNIFICANT" if c.significant else c.why_not
            p = f"{c.p_value:.1e}" if c.p_value > 0 else "<1e-300"
            lines.append(f"  {c.effect:<18}{_pct(c.result.fit['ay']):>8}{_pct(c.result.fit['r']):>8}"
                         f"{c.lr:9.0f}{p:>10}   {verdict}")
        best = d.best
        if best is not None:
            lines.append(f"  => {best.effect}: {best.explanation}")
            params = ", ".join(f"{n} = {v:.4g} {best.result.units[n]}" for n, v in best.result.params().items()
                               if best.result.owners.get(n) == best.effect)
            lines.append(f"     ({params}; add it with --model {d.model}+{best.effect})")
        elif d.base.fit["ay"] >= d.floor["ay"] - 0.5 and d.base.fit["r"] >= d.floor["r"] - 0.5:
            lines.append("  => nothing significant is missing: the model is at the noise floor of this data")
        else:
            lines.append("  => no candidate of the catalogue explains the remaining error significantly; "
                         "the gap to the noise floor may be an effect not in the catalogue (write one: "
                         "docs/writing_an_effect.md)")
        lines.append("")
    return "\n".join(lines).rstrip()


def comparison_text(entries) -> str:
    lines = []
    names = [e["model"] for e in entries]
    w = max(14, max(len(n) for n in names) + 2)
    lines.append(f"{'model':<{w}}{'fit ay':>8}{'fit r':>8}{'AIC':>12}{'BIC':>12}{'white':>8}{'indep.':>8}")
    for e in entries:
        lines.append(f"{e['model']:<{w}}{_pct(e['fit']['ay']):>8}{_pct(e['fit']['r']):>8}{e['aic']:12.0f}"
                     f"{e['bic']:12.0f}{'ay r' if all(e['white'].values()) else ','.join(k for k, v in e['white'].items() if v) or 'no':>8}"
                     f"{'yes' if all(e['independent'].values()) else 'no':>8}")
    lines.append(f"{'noise floor':<{w}}{_pct(entries[0]['noise_floor']['ay']):>8}{_pct(entries[0]['noise_floor']['r']):>8}")
    lines.append("  (AIC/BIC from the Gaussian likelihood; white: residual autocorrelation inside the 99% band; "
                 "indep.: residual-steer cross-correlation inside it)")
    for title, key in (("fit per frequency band", "by_band"), ("fit per |ay| bin", "by_ay"), ("fit per run", "by_run")):
        lines.append("")
        lines.append(title + "  (ay / r)")
        rows = list(entries[0][key])
        for row in rows:
            cells = "".join(f"{_pct(e[key][row]['ay'])}/{_pct(e[key][row]['r']).strip():<7}" for e in entries)
            lines.append(f"  {row:<28}{cells}")
        lines.append(f"  {'':<28}" + "".join(f"{n[:14]:<15}" for n in names))
    return "\n".join(lines)
