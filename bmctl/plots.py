"""Figures (matplotlib, Agg backend): the paper's Fig. 9 and Fig. 12 analogues."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .io import pyplot, savefig

plt = pyplot()


def pdf_over_time(path: Path, axis: np.ndarray, pdfs: np.ndarray, times_h: Sequence[float], xlabel: str,
                  title: str, xmax: float | None = None) -> None:
    """Population-fraction pdfs p(x) at each recorded time, as curves coloured by time (Fig. 9a/b analogue)."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    cmap = plt.get_cmap("viridis")
    tmax = max(max(times_h), 1e-9)
    for t, p in zip(times_h, pdfs):
        ax.plot(axis, p, color=cmap(t / tmax), lw=1.2)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, tmax))
    fig.colorbar(sm, ax=ax, label="batch time t (h)")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("population fraction p per bin")
    ax.set_title(title)
    if xmax is not None:
        ax.set_xlim(0, xmax)
    ax.grid(alpha=0.3)
    savefig(fig, path, dpi=120, bbox_inches="tight")


R_LABEL = "irregularity r = 1 − πs/L (0 = round)"

#: axis labels (with units and weighting) of the quantities the package plots
QUANTITY_LABELS = {
    "s_mean_um": "mean size s (µm, by number)", "s_std_um": "std of size s (µm, by number)",
    "s_mode_um": "mode of size s (µm, by number)", "r_mean": "mean irregularity r", "r_std": "std of irregularity r",
    "r_mode": "mode of irregularity r", "temperature_c": "vial temperature (°C)", "hardening": "hardening h (0-1)",
    "d10_um": "D10 (µm, by volume)", "d50_um": "D50 (µm, by volume)", "d90_um": "D90 (µm, by volume)",
    "span": "span (D90 − D10)/D50 (by volume)", "s_mean_area_um": "mean size (µm, by area; Sauter D[3,2])",
    "s_mode_area_um": "mode of size (µm, by area)", "gamma_mult": "bonding factor γ / γ_card",
    "delta_mult": "fracture factor δ / δ_card",
}


def quantity_label(key: str) -> str:
    """Axis label of a moment/state name (units and weighting), or the name itself if unknown."""
    return QUANTITY_LABELS.get(key, key)


def moments_over_time(path: Path, t_h: np.ndarray, cols: dict[str, np.ndarray], title: str) -> None:
    """Size statistics (number- and volume-weighted), irregularity r and vial temperature over time
    (Fig. 12 analogue)."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    if "d50_um" in cols:
        ax.fill_between(t_h, cols["d10_um"], cols["d90_um"], color="tab:orange", alpha=0.18, lw=0,
                        label="D10–D90 (by volume)")
        ax.plot(t_h, cols["d50_um"], color="tab:orange", marker="s", ms=3, label="D50 (by volume)")
    if "s_mode_area_um" in cols:
        ax.plot(t_h, cols["s_mode_area_um"], color="tab:green", marker="^", ms=3, ls="--", label="mode (by area)")
    for key, lab, c in (("s_mean_um", "mean (by number)", "tab:blue"), ("s_std_um", "std (by number)", "tab:purple"),
                        ("s_mode_um", "mode (by number)", "0.35")):
        ax.plot(t_h, cols[key], marker="o", ms=3, label=lab, color=c)
    ax.set_xlabel("batch time t (h)"), ax.set_ylabel("particle size s (µm)")
    ax.set_title("particle size"), ax.legend(fontsize=7), ax.grid(alpha=0.3)
    ax = axes[1]
    for key, lab in (("r_mean", "mean r"), ("r_std", "std r"), ("r_mode", "mode r")):
        ax.plot(t_h, cols[key], marker="o", ms=3, label=lab)
    ax.set_xlabel("batch time t (h)"), ax.set_ylabel(R_LABEL), ax.set_title("particle shape (by number)")
    ax.legend(fontsize=8), ax.grid(alpha=0.3)
    ax = axes[2]
    ax.plot(t_h, cols["temperature_c"], color="tab:red", marker="o", ms=3, label="vial wall")
    ax.set_xlabel("batch time t (h)"), ax.set_ylabel("vial temperature (°C)"), ax.set_title("temperature")
    ax.legend(fontsize=8), ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.subplots_adjust(left=0.05, right=0.985, bottom=0.13, top=0.86, wspace=0.24)  # fixed: no measuring draw
    savefig(fig, path, dpi=120)


def log_size_bins(s_edges_um: np.ndarray, per_decade: int = 20, s_min_um: float = 1.0) -> np.ndarray:
    """Edges of log-spaced size bins made of whole raster bins (indices into ``s_edges_um``).

    Returns increasing indices k such that bin j spans raster bins k[j] .. k[j+1] - 1; every
    log bin holds at least one 1-µm raster bin, so rebinning is exact.
    """
    lo = max(s_min_um, float(s_edges_um[1]))
    target = np.exp(np.arange(np.log(lo), np.log(s_edges_um[-1]), np.log(10) / per_decade))
    k = np.unique(np.searchsorted(s_edges_um, target))
    return np.unique(np.concatenate([[0], k[(k > 0) & (k < s_edges_um.size - 1)], [s_edges_um.size - 1]]))


def size_densities(s_edges_um: np.ndarray, p_s: np.ndarray, per_decade: int = 20):
    """Number and volume densities per ln s on log bins, from number fractions on the 1-µm raster.

    Parameters
    ----------
    s_edges_um : ndarray, (n + 1,)
        Raster edges (µm).
    p_s : ndarray, (..., n)
        Number fractions per raster bin.
    per_decade : int, optional
        Log bins per decade of size, at most (:func:`log_size_bins`: each is made of whole raster bins).

    Returns
    -------
    centres_um, edges_um, q0, q3, Q3
        Geometric bin centres and edges (µm) of the log bins; number density q0 and volume
        density q3 per unit ln s on them, (..., nb); cumulative volume fraction Q3 at the raster's
        upper edges, (..., n). Volume weights use each raster bin's centre (s^3).
    """
    k = log_size_bins(s_edges_um, per_decade)
    c = 0.5 * (s_edges_um[1:] + s_edges_um[:-1])
    pv = p_s * c**3
    pv = pv / np.maximum(pv.sum(axis=-1, keepdims=True), 1e-300)
    edges = s_edges_um[k]
    edges = np.where(edges <= 0, 0.5 * s_edges_um[1], edges)
    dln = np.diff(np.log(edges))
    q0 = np.add.reduceat(p_s, k[:-1], axis=-1) / dln
    q3 = np.add.reduceat(pv, k[:-1], axis=-1) / dln
    return np.sqrt(edges[1:] * edges[:-1]), edges, q0, q3, np.cumsum(pv, axis=-1)


def pick_times(times_h: Sequence[float], n: int = 6) -> list[int]:
    """Indices of up to ``n`` recorded times: the start, then geometrically spaced to the end
    (milling changes the powder fastest early: 0, 1, 2, 4, 8, 12 h for an hourly 12-h run)."""
    m = len(times_h)
    if m <= n:
        return list(range(m))
    k = np.unique(np.round(np.geomspace(1, m - 1, n - 1)).astype(int))
    return [0, *k.tolist()]


SIZE_TICKS_UM = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)

#: tick mantissas per decade of a log size axis, from coarse to fine: the finer sets are used when
#: fewer than two ticks of the coarser ones fall in the axis range (a narrow size range)
SIZE_TICK_STEPS = ((1,), (1, 2, 5), (1, 2, 3, 4, 5, 6, 8), (1, 2, 3, 4, 5, 6, 7, 8, 9))


def size_ticks(lo: float, hi: float, most: int = 12) -> list[float]:
    """Tick positions of a log size axis from ``lo`` to ``hi`` (µm): 1-2-5 per decade (1 per decade
    when that gives more than ``most``); when fewer than two of those fall in the range, finer ones
    (1-2-3-4-5-6-8, then every whole mantissa) that give at least three; a range too narrow for
    any of these (35-48 µm) gets evenly spaced round numbers.

    Examples
    --------
    >>> size_ticks(7, 250)
    [10.0, 20.0, 50.0, 100.0, 200.0]
    >>> size_ticks(26, 70)
    [30.0, 40.0, 50.0, 60.0]
    >>> size_ticks(35, 48)
    [35.0, 40.0, 45.0]
    """
    lo, hi = (float(lo), float(hi)) if lo <= hi else (float(hi), float(lo))
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= 0:
        return []
    lo = max(lo, hi * 1e-12)
    eps = 1e-9 * hi
    decades = range(int(np.floor(np.log10(lo))) - 1, int(np.ceil(np.log10(hi))) + 1)

    def within(steps):
        return [float(f"{m * 10.0 ** d:.12g}") for d in decades for m in steps if lo - eps <= m * 10.0 ** d <= hi + eps]

    ticks = within((1, 2, 5))
    if len(ticks) > most:
        return within((1,))
    if len(ticks) >= 2:
        return ticks
    for steps in SIZE_TICK_STEPS[2:]:  # finer: while they give fewer than three (30 and 40 only on 30-48 µm)
        ticks = within(steps)
        if len(ticks) >= 3:
            return ticks
    from matplotlib.ticker import MaxNLocator

    return [float(f"{v:.12g}") for v in MaxNLocator(nbins=6, steps=[1, 2, 5, 10]).tick_values(lo, hi)
            if lo - eps <= v <= hi + eps]


def _plain_number(value: float, _pos=None) -> str:
    """A size tick's label: the plain number (50, 2.5, 1000), never a power of ten."""
    return f"{value:.6g}" if abs(value) < 1e6 else f"{value:.0f}"


def log_size_axis(ax, axis: str = "x") -> None:
    """Log size axis with plain µm tick labels (1, 2, 5, 10, 20, ...; finer on a narrow range,
    :func:`size_ticks`, chosen when the axis is drawn, so its limits may be set later).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes whose size axis is already on a log scale.
    axis : {"x", "y"}
        Which axis holds the sizes.
    """
    from matplotlib.ticker import FuncFormatter, Locator, NullFormatter

    class SizeLocator(Locator):
        def __call__(self):
            return self.tick_values(*self.axis.get_view_interval())

        def tick_values(self, vmin, vmax):
            return size_ticks(vmin, vmax)

    a = ax.xaxis if axis == "x" else ax.yaxis
    a.set_major_locator(SizeLocator())
    a.set_major_formatter(FuncFormatter(_plain_number))
    a.set_minor_formatter(NullFormatter())


def size_distributions(path: Path, s_edges_um: np.ndarray, p_s: np.ndarray, times_h: Sequence[float],
                       d50_um: Sequence[float], title: str, n_panels: int = 6) -> None:
    """Small multiples of the size distribution at selected times on a log size axis.

    Each panel: number density per ln s (bars, left axis), volume density per ln s (orange line,
    left axis), the cumulative volume fraction (dashed, right axis) and D50 (by volume) marked.
    """
    cen, edges, q0, q3, Q3 = size_densities(s_edges_um, p_s)
    idx = pick_times(times_h, n_panels)
    ncol = min(3, len(idx))  # two records: two panels, no empty third column
    nrow = int(np.ceil(len(idx) / ncol))
    leg_cols = {1: 1, 2: 2}.get(ncol, 4)
    leg_rows = int(np.ceil(4 / leg_cols))
    # fixed margins in inches (tight_layout would draw the 12 axes once more only to measure them, ~1 s):
    # above, the title and the panel titles; below, the tick labels, the axis label and the legend under them
    top_in, bottom_in = 0.62, 0.62 + 0.2 * leg_rows
    height = 3.2 * nrow + 0.2 * leg_rows
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.3 * ncol, height), sharex=True, squeeze=False)
    peak = max(q0[idx].max(), q3[idx].max())
    nz = np.nonzero(q0[idx].max(axis=0) + q3[idx].max(axis=0) > 1e-3 * peak)[0]
    xlo, xhi = edges[max(nz[0] - 1, 0)], edges[min(nz[-1] + 2, edges.size - 1)]
    for j, (a, k) in enumerate(zip(axes.flat, idx)):
        top = 1.15 * max(q0[k].max(), q3[k].max())
        a.stairs(q0[k], edges, fill=True, color="tab:blue", alpha=0.45, label="number density per ln s")
        a.step(edges[:-1], q3[k], where="post", color="tab:orange", lw=1.6, label="volume density per ln s")
        a.set_xscale("log")
        log_size_axis(a)
        a.set_xlim(xlo, xhi), a.set_ylim(0, top)
        a.axvline(d50_um[k], color="k", lw=1, ls=":")
        # the label beside the line, on the side with room: left of it in the right part of the panel
        right = np.log(d50_um[k] / xlo) > 0.55 * np.log(xhi / xlo) if d50_um[k] > 0 else False
        a.text(d50_um[k], 0.93 * top, f"D50 {d50_um[k]:.0f} µm " if right else f" D50 {d50_um[k]:.0f} µm",
               fontsize=8, va="top", ha="right" if right else "left", zorder=5,
               bbox=dict(facecolor="white", alpha=0.8, lw=0, pad=1))
        b = a.twinx()
        b.plot(s_edges_um[1:], 100 * Q3[k], color="0.25", lw=1.1, ls="--", label="cumulative volume (%)")
        b.set_ylim(0, 105)
        if j == min((j // ncol + 1) * ncol, len(idx)) - 1:  # the last panel drawn in its row
            b.set_ylabel("cumulative volume (%)")
        else:
            b.tick_params(right=False, labelright=False)
        a.set_title(f"t = {times_h[k]:g} h", fontsize=10)
        a.grid(alpha=0.3, which="both")
    for a in axes.flat[len(idx):]:
        a.set_visible(False)
    for a in axes[:, 0]:
        a.set_ylabel("density per unit ln s")
    for j, a in enumerate(axes.flat[:len(idx)]):
        if j + ncol >= len(idx):  # no panel below: the lowest of its column
            a.set_xlabel("particle size s (µm, log scale)")
            a.xaxis.set_tick_params(labelbottom=True)
    h1, l1 = axes[0, 0].get_legend_handles_labels()
    fig.legend(h1 + [plt.Line2D([], [], color="0.25", ls="--"), plt.Line2D([], [], color="k", ls=":")],
               l1 + ["cumulative volume fraction (right axis)", "D50: half the volume in smaller particles"],
               loc="lower center", ncol=leg_cols, fontsize=8, frameon=False, bbox_to_anchor=(0.5, 0.0))
    fig.suptitle(title)
    fig.subplots_adjust(left=0.055 * 3 / ncol, right=1 - 0.055 * 3 / ncol, bottom=bottom_in / height,
                        top=1 - top_in / height, wspace=0.25, hspace=0.32)
    savefig(fig, path, dpi=120)


def size_heatmap(path: Path, s_edges_um: np.ndarray, p_s: np.ndarray, times_h: Sequence[float],
                 cols: dict[str, np.ndarray], title: str) -> None:
    """Time–size heat maps of number and volume density per ln s (Fig. 9a analogue), log size axis.

    The number map carries the number-weighted mean; the volume map D10, D50 and D90.
    """
    cen, edges, q0, q3, _ = size_densities(s_edges_um, p_s)
    t = np.asarray(times_h, dtype=float)
    dt = np.diff(t).min() if t.size > 1 else 1.0
    t_edges = np.concatenate([[t[0] - dt / 2], 0.5 * (t[1:] + t[:-1]), [t[-1] + dt / 2]])
    if t.size > 1:  # cells centred on the records, the first and last cut at the batch's start and end
        t_edges[0], t_edges[-1] = t[0], t[-1]
    nz = np.nonzero(q0.max(axis=0) + q3.max(axis=0) > 1e-2 * max(q0.max(), q3.max()))[0]
    ylo, yhi = edges[max(nz[0] - 1, 0)], edges[min(nz[-1] + 2, edges.size - 1)]
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.0), sharey=True)
    for ax, q, lab, lines in (
            (axes[0], q0, "by number", (("s_mean_um", "mean (by number)", "w", "-"),
                                        ("s_mode_um", "mode (by number)", "w", ":"))),
            (axes[1], q3, "by volume", (("d10_um", "D10", "w", ":"), ("d50_um", "D50", "w", "-"),
                                        ("d90_um", "D90", "w", "--")))):
        vmax = q[1:].max() if q.shape[0] > 1 else q.max()  # the narrow starting powder would wash out the rest
        im = ax.pcolormesh(t_edges, edges, q.T, cmap="magma", shading="flat", vmin=0, vmax=vmax)
        for key, name, c, ls in lines:
            if key in cols:
                ax.plot(t, cols[key], color=c, ls=ls, lw=1.4, label=name)
        ax.set_yscale("log"), ax.set_ylim(ylo, yhi), ax.set_xlim(t_edges[0], t_edges[-1])
        log_size_axis(ax, "y")
        ax.set_xlabel("batch time t (h)")
        ax.set_title(f"size distribution {lab}")
        # below the time axis, off the map: inside, it hid the lines it names (D90 of a short batch)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=len(lines), facecolor="0.3",
                  labelcolor="w", framealpha=1.0, edgecolor="0.3", handlelength=3)
        fig.colorbar(im, ax=ax, extend="max", label=f"density per unit ln s ({lab}; t = 0 clipped)")
    axes[0].set_ylabel("particle size s (µm, log scale)")
    fig.suptitle(title)
    fig.subplots_adjust(left=0.06, right=0.975, bottom=0.2, top=0.88, wspace=0.12)  # fixed: no measuring draw
    savefig(fig, path, dpi=120)


def irregularity_distributions(path: Path, r_edges: np.ndarray, p_r: np.ndarray, times_h: Sequence[float],
                               title: str, n_curves: int = 5) -> None:
    """Distribution of the irregularity r at selected times: density on a log axis and cumulative fraction."""
    idx = pick_times(times_h, n_curves)
    w = np.diff(r_edges)
    c = 0.5 * (r_edges[1:] + r_edges[:-1])
    cum = np.cumsum(p_r, axis=-1)
    hi = float(r_edges[min(np.searchsorted(cum[idx].min(axis=0), 0.999) + 2, r_edges.size - 1)])
    cmap = plt.get_cmap("viridis")
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for j, k in enumerate(idx):
        col = cmap(j / max(len(idx) - 1, 1))
        axes[0].step(c, np.where(p_r[k] > 0, p_r[k] / w, np.nan), where="mid", color=col, lw=1.3,
                     label=f"t = {times_h[k]:g} h")
        axes[1].plot(r_edges[1:], 100 * cum[k], color=col, lw=1.5, label=f"t = {times_h[k]:g} h")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("number density per unit r (log scale)")
    axes[0].set_title("density (bins of 0.01)")
    axes[1].set_ylabel("particles with smaller r (%)")
    axes[1].set_title("cumulative fraction by number")
    for ax in axes:
        ax.set_xlim(0, hi), ax.set_xlabel(R_LABEL), ax.grid(alpha=0.3, which="both"), ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.subplots_adjust(left=0.065, right=0.98, bottom=0.12, top=0.86, wspace=0.2)  # fixed: no measuring draw
    savefig(fig, path, dpi=120)


_MOMENT_LABELS = {"s_mean_um": "mean s (µm)", "s_std_um": "std s (µm)", "r_mean": "mean irregularity r",
                  "r_std": "std irregularity r"}


def identify_validation(path: Path, experiments: Sequence, preds: Sequence[np.ndarray], rows: np.ndarray,
                        title: str) -> list[str]:
    """Moment model against the plant ensemble on held-out schedules: the best, the median and the two
    worst (by the mean NRMSE of the four particle moments). Rows: rpm, then each particle moment
    (plant mean with a band of ±1 std across seeds, model line, per-panel NRMSE). Returns the names shown.
    """
    score = rows[:, :4].mean(1)
    order = np.argsort(score)
    roles = {}
    for role, k in (("best", order[0]), ("median", order[len(order) // 2]), ("2nd worst", order[-2]),
                    ("worst", order[-1])):
        roles.setdefault(int(k), role)
    pick = list(roles)
    names = list(_MOMENT_LABELS)
    fig, axes = plt.subplots(1 + len(names), len(pick), figsize=(3.6 * len(pick), 1.9 * (1 + len(names))),
                             sharex=True, squeeze=False)
    for c, k in enumerate(pick):
        e, P = experiments[k], preds[k]
        t = np.arange(e.Y.shape[0]) * e.dt_h
        rpm = e.U[:, 0] * (e.U[:, 1] > 0)
        ax = axes[0, c]
        ax.step(t, np.append(rpm, rpm[-1]), where="post", color="0.3")
        ax.fill_between(t[:-1], 0, rpm * (1 - e.U[:, 1]), step="post", color="tab:blue", alpha=0.15, lw=0)
        ax.set_title(f"{roles[k]}: {e.name}\nmean NRMSE {100 * score[k]:.1f} %", fontsize=9)
        if c == 0:
            ax.set_ylabel("rpm")
        for j, key in enumerate(names):
            ax = axes[1 + j, c]
            ax.fill_between(t, e.Y[:, j] - e.S[:, j], e.Y[:, j] + e.S[:, j], color="0.8", lw=0)
            ax.plot(t, e.Y[:, j], color="k", lw=1.4, label="plant ensemble mean (±1 std of seeds)")
            ax.plot(t, P[:, j], color="tab:orange", lw=1.4, ls="--", label="moment model")
            ax.text(0.98, 0.05, f"{100 * rows[k, j]:.1f} %", transform=ax.transAxes, ha="right", fontsize=8)
            ax.grid(alpha=0.3)
            if c == 0:
                ax.set_ylabel(_MOMENT_LABELS[key])
    for ax in axes[-1]:
        ax.set_xlabel("t (h)")
    axes[1, 0].legend(fontsize=7, loc="best")
    fig.suptitle(title)
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    return [experiments[k].name for k in pick]


def identify_nrmse(path: Path, rows: np.ndarray, rows_defaults: np.ndarray, title: str,
                   target: float = 0.05) -> None:
    """Per-schedule NRMSE of each particle moment (dots), fitted against built-in defaults, with the target."""
    names = list(_MOMENT_LABELS)
    fig, ax = plt.subplots(figsize=(7.5, 4))
    rng = np.random.default_rng(0)  # horizontal jitter of the dots only
    for j in range(len(names)):
        for off, R, col, lab in ((-0.18, rows_defaults, "0.6", "built-in defaults"),
                                 (0.18, rows, "tab:orange", "identified")):
            x = j + off + rng.uniform(-0.07, 0.07, R.shape[0])
            ax.scatter(x, 100 * R[:, j], s=12, color=col, label=lab if j == 0 else None)
            ax.plot([j + off - 0.12, j + off + 0.12], [100 * R[:, j].mean()] * 2, color="k", lw=2)
    ax.axhline(100 * target, color="tab:red", ls=":", label=f"target {100 * target:g} % (mean over schedules)")
    ax.set_xticks(range(len(names)), [_MOMENT_LABELS[k] for k in names])
    ax.set_ylabel("NRMSE per held-out schedule (%)")
    ax.set_yscale("log")
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(plain)
    ax.plot([], [], color="k", lw=2, label="mean over schedules")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title(title)
    savefig(fig, path, dpi=120, bbox_inches="tight")
