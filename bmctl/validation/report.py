"""The whole verification (``bmctl verify``): settings, the run, the table and the figures.

See :mod:`bmctl.validation` and docs/verification.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..config import ModelCard
from .exact import BIAS_ALPHA, Exact, SLOPE_RANGE, X0, Z_BIAS
from .cases import CASES, CaseResult, evaluate
from .engine import Bookkeeping, Energetics, KS_ALPHA, REFERENCE_MOMENTS, ReferenceComparison, bookkeeping, compare_reference, energetics

# --- the whole verification: settings, table, figures ------------------------------------------------

@dataclass(frozen=True)
class Settings:
    """Sizes of the verification runs (``QUICK`` and ``FULL``)."""

    sizes: tuple[int, ...]
    seeds: int
    ref_particles: int
    ref_hours: float
    ref_seeds: int
    collisions: int
    book_particles: int
    book_scale: float


QUICK = Settings(sizes=(500, 2000, 8000), seeds=6, ref_particles=500, ref_hours=0.25, ref_seeds=12,
                 collisions=5000, book_particles=1000, book_scale=0.25)
FULL = Settings(sizes=(1000, 4000, 16000), seeds=8, ref_particles=1000, ref_hours=0.5, ref_seeds=32,
                collisions=20000, book_particles=3000, book_scale=1.0)
ERROR_FACTOR = 3.0  # an rms error above this many expected (i.i.d.) Monte Carlo errors fails


@dataclass
class Report:
    """Everything one verification produced."""

    settings: Settings
    seed: int
    analytic: list[CaseResult]
    energetics: dict[str, Energetics]
    reference: list[ReferenceComparison]
    bookkeeping: list[Bookkeeping]

    @property
    def passed(self) -> bool:
        return all(r[-1] != "FAIL" for r in rows(self))


def run_all(settings: Settings, seed: int, cards: Sequence[ModelCard],
            progress: Callable[[str], None] | None = None) -> Report:
    """Every check with ``settings``.

    Parameters
    ----------
    settings : Settings
        Sizes of the runs (:data:`QUICK`, :data:`FULL`).
    seed : int
        First seed.
    cards : sequence of ModelCard
        Cards for the loop, reference and bookkeeping checks.
    progress : callable, optional
        Called with progress lines.
    """
    seeds = tuple(range(seed, seed + settings.seeds))
    analytic = [evaluate(make(), settings.sizes, seeds, progress=progress) for make in CASES.values()]
    energ, ref, book = {}, [], []
    for card in cards:
        name = card.card.name
        if progress:
            progress(f"{name}: loop energetics")
        energ[name] = energetics(card, card.process.rpm, settings.collisions, seed)
        ref.append(compare_reference(card, settings.ref_hours, settings.ref_particles,
                                     range(seed, seed + settings.ref_seeds), progress=progress))
        if progress:
            progress(f"{name}: long-run bookkeeping")
        book.append(bookkeeping(card, settings.book_particles, seed, settings.book_scale))
    return Report(settings, seed, analytic, energ, ref, book)


HEADER = ("check", "case", "M", "quantity", "error", "expected", "result")


def _ok(flag: bool) -> str:
    return "pass" if flag else "FAIL"


def rows(report: Report) -> list[tuple]:
    """The verification table: one row per quantity (``HEADER``); ``info`` rows are not tests.

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    """
    out = []
    names = {"n": "N rel. error (rms)", "m2": "E[x^2] rel. error (rms)", "ks": "Kolmogorov distance (rms)"}
    for res in report.analytic:
        c = res.case.name
        for M in res.sizes:
            for k, label in names.items():
                err, exp = res.rms[M][k], res.expected[M][k]
                out.append(("analytic", c, M, label, f"{err:.4f}", f"{exp:.4f}", _ok(err <= ERROR_FACTOR * exp)))
        worst = max(res.bias_z, key=lambda key: abs(res.bias_z[key]))
        out.append(("analytic", c, "all", f"bias: max |t| {res.max_z:.2f} ({worst}), of {len(res.bias_z)}",
                    f"p = {res.bias_p:.3f}", f"p > {BIAS_ALPHA:g}", _ok(res.bias_p > BIAS_ALPHA)))
        lo, hi = SLOPE_RANGE
        for k, s in res.slopes.items():
            out.append(("analytic", c, "all", f"slope of log rms {k} vs log M", f"{s:+.2f}", "-0.50",
                        _ok(lo <= s <= hi)))
    for name, e in report.energetics.items():
        z = e.z()
        out.append(("loop", name, "", "hit rate / plant - 1 (overshoot removed)", f"{e.rate_wald / e.rate_plant - 1:+.4f}",
                    f"{e.rate_wald_se / e.rate_plant:.4f}", _ok(abs(z["rate"]) < Z_BIAS)))
        out.append(("loop", name, "", "plastic share cos^2(2psi) - plant", f"{e.plastic_loop - e.plastic_plant:+.4f}",
                    f"{e.plastic_loop_se:.4f}", _ok(abs(z["plastic"]) < Z_BIAS)))
        out.append(("loop", name, "", "mean U_in / plant - 1", f"{e.u_in_loop / e.u_in_plant - 1:+.4f}",
                    f"{e.u_in_loop_se / e.u_in_plant:.4f}", _ok(abs(z["u_in"]) < Z_BIAS)))
        out.append(("loop", name, "", f"overshoot, impacts per collision (of {e.steps_per_collision:.0f})",
                    f"{e.overshoot:.3f}", "(1+CV^2)/2", "info"))
    for cmp in report.reference:
        for k in REFERENCE_MOMENTS:
            a, b = cmp.plant[k], cmp.reference[k]
            se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
            out.append(("reference", cmp.card, cmp.particles, f"{k}: plant - reference (t = {cmp.z[k]:+.2f})",
                        f"{a.mean() - b.mean():+.4f}", f"{se:.4f}", "info"))
        out.append(("reference", cmp.card, cmp.particles, f"moments: max |t| of {len(cmp.z)}",
                    f"p = {cmp.moments_p:.3f}", f"p > {BIAS_ALPHA:g}", _ok(cmp.moments_p > BIAS_ALPHA)))
        for k, (d, p) in cmp.ks.items():
            out.append(("reference", cmp.card, cmp.particles, f"KS final {k} (p = {p:.3f})", f"{d:.4f}",
                        f"p > {KS_ALPHA:g}", _ok(p > KS_ALPHA)))
    for b in report.bookkeeping:
        out.append(("bookkeeping", b.card, b.particles, f"area change in a round's events ({b.hours:g} h)",
                    f"{b.area_err:.1e}", "< 1e-12", _ok(b.area_err < 1e-12)))
        out.append(("bookkeeping", b.card, b.particles, "w sum(s^2) / X - 1 at the end", f"{b.total_area_err:.1e}",
                    "< 1e-12", _ok(b.total_area_err < 1e-12)))
        out.append(("bookkeeping", b.card, b.particles, "log N vs event balance (z)", f"{b.n_z:+.2f}",
                    f"|z| < {Z_BIAS:g}", _ok(abs(b.n_z) < Z_BIAS)))
        out.append(("bookkeeping", b.card, b.particles, f"impacts {b.counts[0]} vs hit rate (z)", f"{b.impacts_z:+.2f}",
                    f"|z| < {Z_BIAS:g}", _ok(abs(b.impacts_z) < Z_BIAS)))
        out.append(("bookkeeping", b.card, b.particles, "min s (µm); r range", f"{b.s_min * 1e6:.3f}; "
                    f"[{b.r_min:.3f}, {b.r_max:.3f}]", "> 0; [0, 1)", _ok(b.s_min > 0 and b.r_min >= 0 and b.r_max < 1)))
    return out


def format_table(table: Sequence[tuple]) -> str:
    """Plain-text table with aligned columns.

    Parameters
    ----------
    table : sequence of tuple
        Rows of :func:`rows`.
    """
    cells = [HEADER] + [tuple(str(c) for c in row) for row in table]
    widths = [max(len(r[k]) for r in cells) for k in range(len(HEADER))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _pdf_panel(ax, res: CaseResult) -> None:
    """Exact against simulated distributions of x / x0 at the case's times (largest M, pooled seeds)."""
    M = res.sizes[-1]
    colors = ("tab:blue", "tab:orange", "tab:green")
    for ti, tau in enumerate(res.case.times):
        ex = res.case.exact(tau)
        xs = np.concatenate([r.samples[ti] for r in res.runs[M]]) / X0
        col = colors[ti % len(colors)]
        if ex.support is not None:
            k = np.arange(1, min(int(xs.max()), 60) + 1)
            f_sim = np.bincount(np.rint(xs).astype(int), minlength=k[-1] + 1)[1:k[-1] + 1] / xs.size
            f_ex = np.diff(ex.cdf(np.concatenate([[0.0], k]) * X0))
            ax.plot(k, f_ex, "-", color=col, lw=1.2, label=f"exact, tau={tau:g}")
            ax.plot(k, f_sim, "o", color=col, ms=3, label=f"simulated, tau={tau:g}")
            ax.set_xlabel("k = x / x0")
            ax.set_ylabel("number fraction")
        else:
            hi = float(np.quantile(xs, 0.995))
            edges = np.linspace(0.0, hi, 41)
            cont = xs < 1.0 - 1e-9 if ex.atoms else np.ones(xs.size, bool)
            h = np.histogram(xs[cont], bins=edges)[0] / (xs.size * np.diff(edges))
            mid = 0.5 * (edges[1:] + edges[:-1])
            dens = np.diff(ex.cdf(edges * X0, left=True)) / np.diff(edges)
            ax.plot(mid, dens, "-", color=col, lw=1.2, label=f"exact, tau={tau:g}")
            ax.plot(mid, h, "o", color=col, ms=3, label=f"simulated, tau={tau:g}")
            if ex.atoms:
                a_ex = 1.0 - float(ex.cdf(X0, left=True))
                a_sim = float(np.mean(~cont))
                ax.annotate(f"unbroken: {a_sim:.3f} (exact {a_ex:.3f})", (0.35, 0.9 - 0.08 * ti), xycoords="axes fraction",
                            color=col, fontsize=7)
            ax.set_xlabel("x / x0 (x = s^2, x0 = (40 µm)^2)")
            ax.set_ylabel("number density")
    ax.set_yscale("log")
    ax.set_title(f"{res.case.name} (M = {M}, {len(res.seeds)} seeds)", fontsize=9)
    ax.legend(fontsize=6, ncol=2)
    ax.grid(alpha=0.3)


def analytic_figure(report: Report, path) -> None:
    """Exact and simulated distributions of every analytic case (one panel per case).

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    path : path-like
        PNG file (written atomically).
    """
    from ..io import pyplot, savefig

    plt = pyplot()

    n = len(report.analytic)
    fig, axes = plt.subplots(2, (n + 1) // 2, figsize=(11, 8))
    for ax, res in zip(np.ravel(axes), report.analytic):
        _pdf_panel(ax, res)
    fig.suptitle("bmctl verify: analytic population balances vs the plant's Monte Carlo engine")
    fig.tight_layout()
    savefig(fig, path, dpi=110)


def reference_figure(report: Report, path) -> None:
    """Final s and r distributions of the plant and the reference, pooled over seeds, per card.

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    path : path-like
        PNG file (written atomically).
    """
    from ..io import pyplot, savefig
    from ..plots import R_LABEL

    plt = pyplot()

    n = len(report.reference)
    fig, axes = plt.subplots(2, n, figsize=(max(4 * n, 6.0), 6.8), squeeze=False)
    for col, cmp in enumerate(report.reference):
        for row, (a, b, label, ylabel) in enumerate(((cmp.plant_s, cmp.ref_s, "size s (µm)", "density (1/µm)"),
                                                     (cmp.plant_r, cmp.ref_r, R_LABEL, "density (log scale)"))):
            ax = axes[row, col]
            pa, pb = np.concatenate(a), np.concatenate(b)
            hi = float(np.quantile(np.concatenate([pa, pb]), 0.995))
            edges = np.linspace(0.0, hi, 41)
            ax.hist(pa, bins=edges, density=True, histtype="step", lw=1.4, label="plant (batched)")
            ax.hist(pb, bins=edges, density=True, histtype="step", lw=1.4, ls="--", label="reference (one at a time)")
            ax.set_xlabel(f"{label}\n(99.5 % of particles shown)", fontsize=9)
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
            if row == 1:
                ax.set_yscale("log")
            d, p = cmp.ks["s" if row == 0 else "r"]
            ax.set_title(f"{cmp.card}\nKS {d:.3f}, p = {p:.2f}", fontsize=8)
            if row == 0 and col == 0:
                ax.legend(fontsize=7)
    fig.suptitle(f"plant vs reference after {report.reference[0].hours:g} h, M = {report.reference[0].particles}, "
                 f"{len(report.reference[0].seeds)} seeds")
    fig.tight_layout()
    savefig(fig, path, dpi=110)
