"""Particle-filter evidence study: coverage, parameter trajectories, error vs sample size.

Run (full study, ~7 min on one busy core; the tables of docs/estimation.md):

    python benchmarks/pf_study.py --out out/pf_study                      # summary.md, runs.npz, study.png
    python benchmarks/pf_study.py --laws --out out/pf_study               # laws.md (law-misfit table)
    python benchmarks/pf_study.py --ablation --seeds 10 --out out/pf_ablation
    python benchmarks/pf_study.py --size-law lognormal --out out/pf_study_lognormal   # n = 50/100/300, log-normal

    quick look:  python benchmarks/pf_study.py --seeds 3 --hours 6 --out out/pf_study_quick

Truth: the stochastic PLANT (M = 5000 particles) of the lab card with gamma and delta off
by 30 % (gamma x1.3, delta x0.7, and the reverse), 12 h of the card's recipe (300 rpm),
a micrograph sample every hour through ``bmctl.measure.sampler.micrograph_sample``. The
filter (N = 1000 particles, default settings) runs the moment model of the unmodified card.
Variants (same plant trajectory and, for equal n, the same samples): Weibull size law with
n = 50, 100, 300 measured particles per sample, and the log-normal size law at n = 300.
20 seeds per scenario. See bmctl/validation/study.py for what 'truth' means.

Writes to --out: summary.md (the tables quoted in docs/estimation.md), runs.npz (every
estimate and truth), study.png (parameter trajectories, error vs n, coverage).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bmctl.config import card_schedule, load_card  # noqa: E402
from bmctl.validation import study as S  # noqa: E402


def _sha(path: str) -> str:
    import hashlib

    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]
    except OSError:
        return "(built-in defaults)"


class Cells:
    """Values of one results file, recorded as the Markdown tables are printed: each cell is
    printed with its marker (``bmctl.results.marked``), so a table pasted into a doc is checked."""

    def __init__(self, name: str):
        self.name, self.values = name, {}

    def __call__(self, key: str, value, fmt: str = "{:.2f}") -> str:
        from bmctl.results import marked

        node = self.values
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = float(value)
        return marked(self.name, key, float(value), fmt)


def sk(sc) -> str:
    """Scenario key without dots: (1.3, 0.7) -> 'g1p3_d0p7'."""
    return f"g{sc[0]:g}_d{sc[1]:g}".replace(".", "p")


def cfg_rpm(cfg: S.StudyConfig) -> float:
    return float(load_card(cfg.card).process.rpm)


MOM = ("s_mean", "s_std", "r_mean", "r_std")


def summarise(cfg: S.StudyConfig, res: dict, model, c: Cells) -> str:
    lines = []
    card = load_card(cfg.card)
    segs = card_schedule(card, cfg.hours)
    lines.append(f"# Particle-filter study ({cfg.card}, coefficients: {model.coeffs_source})\n")
    lines.append(f"{len(cfg.seeds)} seeds per scenario, {cfg.hours:g} h recipe, sample every {cfg.every_h:g} h, "
                 f"plant M = {cfg.plant_particles}, filter N = {cfg.filter_particles}; coefficient file sha256 "
                 f"{_sha(model.coeffs_source)}.\n")
    lines.append("## The moment model's one-step error from the true moments (RMS ln(model/plant) over the sample times)\n")
    lines.append("| scenario | model told p | s_mean | s_std | r_mean | r_std |")
    lines.append("|---|---|---|---|---|---|")
    for sc, runs in res.items():
        tm = np.mean([r["truth"] for r in runs], axis=0)
        x = tm[:, :6]  # the plant's moments, temperature and hardening: the model's state
        prev = np.vstack([model.x0()[None, :], x[:-1]])
        for p in ((1.0, 1.0), sc):
            pred = model.step(prev, np.array([cfg_rpm(cfg), 1.0]), cfg.every_h, np.array(p))
            rms = np.sqrt(np.mean(np.log(pred[:, :4] / tm[:, :4]) ** 2, axis=0))
            told = "told" if p == sc else "card"
            lines.append(f"| x{sc[0]:g}, x{sc[1]:g} | ({p[0]:g}, {p[1]:g}) | " + " | ".join(
                c(f"one_step.{sk(sc)}.{told}.{n}", v, "{:.3f}") for n, v in zip(MOM, rms)) + " |")
    lines.append("")
    lines.append("## Coverage of the true moments by the 90 % intervals (share of run x time pairs)\n")
    lines.append("| scenario (gamma, delta) | variant | s_mean | s_std | r_mean | r_std | min ESS | median ESS |")
    lines.append("|---|---|---|---|---|---|---|---|")
    for sc, runs in res.items():
        for v in cfg.variants:
            cov = S.coverage(runs, v.label)
            ess = np.concatenate([r[v.label]["ess"] for r in runs])
            k = f"coverage.{sk(sc)}.{v.label}"
            lines.append(f"| x{sc[0]:g}, x{sc[1]:g} | {v.label} | " + " | ".join(
                c(f"{k}.{n}", x, "{:.2f}") for n, x in zip(MOM, cov))
                + f" | {c(k + '.ess_min', ess.min(), '{:.0f}')} | {c(k + '.ess_median', np.median(ess), '{:.0f}')} |")
    lines.append("\n## Error of the filter mean vs measured particles per sample (median |ln(est/true)|, %)\n")
    lines.append("| scenario | variant | s_mean | s_std | r_mean | r_std | mean 90 % width s_mean (%) | width r_mean (%) |")
    lines.append("|---|---|---|---|---|---|---|---|")
    for sc, runs in res.items():
        for v in cfg.variants:
            e = S.log_errors(runs, v.label)
            w = np.concatenate([np.log(r[v.label]["q95"][:, [0, 2]] / r[v.label]["q05"][:, [0, 2]]) for r in runs])
            k = f"error.{sk(sc)}.{v.label}"
            lines.append(f"| x{sc[0]:g}, x{sc[1]:g} | {v.label} | " + " | ".join(
                c(f"{k}.{n}_pct", 100 * x, "{:.1f}") for n, x in zip(MOM, np.median(e, axis=0)))
                + f" | {c(k + '.width_s_mean_pct', 100 * np.mean(w[:, 0]), '{:.1f}')} | "
                f"{c(k + '.width_r_mean_pct', 100 * np.mean(w[:, 1]), '{:.1f}')} |")
    lines.append("\n## Parameters (gamma_mult / delta_mult): truth and estimates (mean over seeds of the filter mean "
                 "[mean 90 % limits])\n")
    times = res[next(iter(res))][0]["t_h"]
    show = [k for k, t in enumerate(times) if t in (1, 3, 6, 12) or k == len(times) - 1]
    show = sorted(set(show))
    hdr = "| scenario | variant | truth (gamma, delta) | model-optimal | " + " | ".join(
        f"t = {times[k]:g} h" for k in show) + " | \\|ln(est/truth)\\|, gamma / delta: start -> end |"
    lines.append(hdr)
    lines.append("|" + "---|" * (5 + len(show)))
    for sc, runs in res.items():
        truth_mean = np.mean([r["truth"] for r in runs], axis=0)
        pt = S.pseudo_true_multipliers(model, truth_mean, segs, times)
        for v in cfg.variants:
            if v.n != max(x.n for x in cfg.variants):
                continue
            tr = S.param_trajectory(runs, v.label)
            kp = f"parameters.{sk(sc)}.{v.label}"
            cells = []
            for k in show:
                tk = f"{kp}.t{times[k]:g}h".replace(".", "p") if times[k] != int(times[k]) else f"{kp}.t{int(times[k])}h"
                cells.append(" / ".join(f"{c(f'{tk}.{nm}.mean', tr['mean'][k, i])} [{c(f'{tk}.{nm}.q05', tr['q05'][k, i])}, "
                                        f"{c(f'{tk}.{nm}.q95', tr['q95'][k, i])}]" for i, nm in enumerate(("gamma", "delta"))))
            d0 = np.abs(np.log(sc))  # the filter starts at the card, p = (1, 1)
            d1 = np.abs(np.log(tr["mean"][-1, :2] / np.asarray(sc)))
            lines.append(f"| x{sc[0]:g}, x{sc[1]:g} | {v.label} | ({sc[0]:g}, {sc[1]:g}) | "
                         f"({c(kp + '.pseudo_true.gamma', pt[0])}, {c(kp + '.pseudo_true.delta', pt[1])}) | "
                         + " | ".join(cells) + f" | {c(kp + '.ln_error_start.gamma', d0[0])} -> {c(kp + '.ln_error_end.gamma', d1[0])}"
                         f" / {c(kp + '.ln_error_start.delta', d0[1])} -> {c(kp + '.ln_error_end.delta', d1[1])} |")
    return "\n".join(lines) + "\n"


def figure(path: Path, cfg: S.StudyConfig, res: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bmctl.io import savefig

    scs = list(res)
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    for i, sc in enumerate(scs[:2]):
        runs = res[sc]
        for j, (pname, col) in enumerate((("gamma_mult", 0), ("delta_mult", 1))):
            ax = axes[i, j]
            for v in cfg.variants:
                if v.size_law != "weibull":
                    continue
                tr = S.param_trajectory(runs, v.label)
                ax.plot(tr["t_h"], tr["mean"][:, col], marker="o", ms=3, label=v.label)
                if v.n == max(x.n for x in cfg.variants):
                    ax.fill_between(tr["t_h"], tr["q05"][:, col], tr["q95"][:, col], alpha=0.15)
            ax.axhline(sc[col], color="k", ls="--", lw=1, label="nominal truth")
            ax.axhline(1.0, color="gray", ls=":", lw=1)
            ax.set_title(f"{pname}, plant gamma x{sc[0]:g}, delta x{sc[1]:g}", fontsize=9)
            ax.set_xlabel("t (h)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    ax = axes[0, 2]
    ns = sorted({v.n for v in cfg.variants if v.size_law == "weibull"})
    labels_all = {v.label for v in cfg.variants}
    ns = [n for n in ns if f"weibull-n{n}" in labels_all]
    for m, name in enumerate(S.MOMENTS):
        med = [np.median(np.concatenate([S.log_errors(res[sc], f"weibull-n{n}")[:, m] for sc in scs])) for n in ns]
        ax.plot(ns, 100 * np.array(med), marker="o", label=name)
    ax.set_xscale("log")
    ax.set_xlabel("measured particles per sample n")
    ax.set_ylabel("median |ln(est/true)| (%)")
    ax.set_title("error vs sample size (both scenarios)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax = axes[1, 2]
    labels = [v.label for v in cfg.variants]
    cov = np.array([np.mean([S.coverage(res[sc], lab) for sc in scs], axis=0) for lab in labels])
    x = np.arange(len(S.MOMENTS))
    for k, lab in enumerate(labels):
        ax.bar(x + (k - len(labels) / 2 + 0.5) * 0.8 / len(labels), cov[k], width=0.8 / len(labels), label=lab)
    ax.axhline(0.9, color="k", ls="--", lw=1)
    ax.axhline(0.8, color="r", ls=":", lw=1)
    ax.set_xticks(x, S.MOMENTS, fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_title("coverage of the 90 % intervals", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    savefig(fig, path, dpi=110)


def laws_table(a) -> int:
    """Write laws.md: relative error (%) of each law's pseudo-true moments vs the plant's."""
    from bmctl.estimate.likelihood import LAW_MISFIT, SIZE_LAWS
    from bmctl.io import write_text

    rows = S.law_misfit(a.card)
    lines = ["# Law misfit: pseudo-true moments of the filter's likelihood vs the plant (20,000 particles)\n",
             "Relative error (%) of the maximum-likelihood moments of a 20,000-particle micrograph sample "
             "(bmctl.measure.sampler, noise 0.03) under each size law (r: Beta through the noise model).\n",
             "| gamma, delta | t (h) | true s_mean, s_std, r_mean, r_std | " + " | ".join(
                 f"{law}: s_mean, s_std, r_mean, r_std" for law in SIZE_LAWS) + " |",
             "|---|---|---|" + "---|" * len(SIZE_LAWS)]
    worst = {law: np.zeros(4) for law in SIZE_LAWS}
    c = Cells("pf_study_laws")
    for r in rows:
        cells = []
        k = f"{sk(r['scenario'])}.t{int(r['t_h'])}h"
        for law in SIZE_LAWS:
            rel = r[law] / r["truth"] - 1
            worst[law] = np.maximum(worst[law], np.abs(rel))
            cells.append(", ".join(c(f"{k}.{law}.{n}_pct", 100 * v, "{:+.1f}") for n, v in zip(MOM, rel)))
        tr = r["truth"]
        lines.append(f"| x{r['scenario'][0]:g}, x{r['scenario'][1]:g} | {r['t_h']:g} | {c(k + '.truth.s_mean', tr[0], '{:.1f}')}, "
                     f"{c(k + '.truth.s_std', tr[1], '{:.1f}')}, {c(k + '.truth.r_mean', tr[2], '{:.3f}')}, "
                     f"{c(k + '.truth.r_std', tr[3], '{:.3f}')} | " + " | ".join(cells) + " |")
    lines.append("")
    for law in SIZE_LAWS:
        lines.append(f"- {law}: largest |error| " + ", ".join(f"{c(f'worst.{law}.{n}_pct', 100 * v, '{:.1f}')} %"
                                                              for n, v in zip(MOM, worst[law]))
                     + f"; floor used (LAW_MISFIT): {LAW_MISFIT[law]}")
    text = "\n".join(lines) + "\n"
    out = Path(a.out)
    write_text(out / "laws.md", text)
    if not a.no_results:
        from bmctl.results import write_results

        write_results("pf_study_laws", c.values, settings={"card": a.card}, command="python benchmarks/pf_study.py --laws")
    print(text)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--plant-particles", type=int, default=5000)
    ap.add_argument("--filter-particles", type=int, default=1000)
    ap.add_argument("--card", default="models/alni-1to1-300rpm-lab.toml")
    ap.add_argument("--out", default="out/pf_study")
    ap.add_argument("--ablation", action="store_true",
                    help="compare the bootstrap/untempered, guided/untempered and default filters (n = 300)")
    ap.add_argument("--laws", action="store_true",
                    help="only the law-misfit table: each size law's pseudo-true moments on 20,000-particle samples")
    ap.add_argument("--size-law", choices=("weibull", "lognormal"), default=None,
                    help="run n = 50, 100, 300 with this size law only (default: the standard variant set)")
    ap.add_argument("--no-results", action="store_true", help="do not write results/<name>.json")
    a = ap.parse_args(argv)
    if a.laws:
        return laws_table(a)
    cfg = S.StudyConfig(card=a.card, seeds=tuple(range(a.seeds)), hours=a.hours, plant_particles=a.plant_particles,
                        filter_particles=a.filter_particles)
    if a.ablation:
        cfg.variants = S.ABLATION
    elif a.size_law is not None:
        cfg.variants = tuple(S.Variant(n, a.size_law) for n in (50, 100, 300))
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(cfg.card)
    t0 = time.time()

    def progress(sc, seed):
        print(f"  scenario {sc} seed {seed} done ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)

    res = S.run_study(cfg, progress)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    name = "pf_study_ablation" if a.ablation else (f"pf_study_{a.size_law}" if a.size_law else "pf_study")
    cells = Cells(name)
    text = summarise(cfg, res, model, cells) + f"\nwall time {time.time() - t0:.0f} s\n"
    if not a.no_results:
        from bmctl.results import write_results

        cmd = "python benchmarks/pf_study.py" + (" --ablation --seeds 10" if a.ablation else "") + (
            f" --size-law {a.size_law}" if a.size_law else "")
        write_results(name, dict(cells.values, wall_s=time.time() - t0, load_average=list(os.getloadavg())),
                      settings={"seeds": a.seeds, "hours": a.hours, "plant_particles": a.plant_particles,
                                "filter_particles": a.filter_particles, "card": a.card,
                                "variants": [v.label for v in cfg.variants],
                                "scenarios": [list(x) for x in cfg.scenarios]}, command=cmd)
    from bmctl.io import savez, write_text

    write_text(out / "summary.md", text)
    arrays = {}
    for sc, runs in res.items():
        key = f"g{sc[0]:g}_d{sc[1]:g}"
        arrays[f"{key}_truth"] = np.array([r["truth"] for r in runs])
        for v in cfg.variants:
            for f in ("mean", "q05", "q95", "ess"):
                arrays[f"{key}_{v.label}_{f}"] = np.array([r[v.label][f] for r in runs])
    arrays["t_h"] = res[cfg.scenarios[0]][0]["t_h"]
    savez(out / "runs.npz", **arrays)
    figure(out / "study.png", cfg, res)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
