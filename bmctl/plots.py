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
    fig.colorbar(sm, ax=ax, label="milling time t (h)")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("population fraction p per bin")
    ax.set_title(title)
    if xmax is not None:
        ax.set_xlim(0, xmax)
    ax.grid(alpha=0.3)
    savefig(fig, path, dpi=120, bbox_inches="tight")


def moments_over_time(path: Path, t_h: np.ndarray, cols: dict[str, np.ndarray], title: str) -> None:
    """Mean, std and mode of s and r, and vial temperature, over time (Fig. 12 analogue)."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    ax = axes[0]
    for key, lab in (("s_mean_um", "mean s"), ("s_std_um", "std s"), ("s_mode_um", "mode s*")):
        ax.plot(t_h, cols[key], marker="o", ms=3, label=lab)
    ax.set_xlabel("t (h)"), ax.set_ylabel("size s (um)"), ax.legend(), ax.grid(alpha=0.3)
    ax = axes[1]
    for key, lab in (("r_mean", "mean r"), ("r_std", "std r"), ("r_mode", "mode r*")):
        ax.plot(t_h, cols[key], marker="o", ms=3, label=lab)
    ax.set_xlabel("t (h)"), ax.set_ylabel("aspect ratio r"), ax.legend(), ax.grid(alpha=0.3)
    ax = axes[2]
    ax.plot(t_h, cols["temperature_c"], color="tab:red", marker="o", ms=3)
    ax.set_xlabel("t (h)"), ax.set_ylabel("vial temperature (°C)"), ax.grid(alpha=0.3)
    fig.suptitle(title)
    savefig(fig, path, dpi=120, bbox_inches="tight")


_MOMENT_LABELS = {"s_mean_um": "mean s (um)", "s_std_um": "std s (um)", "r_mean": "mean r", "r_std": "std r"}


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
