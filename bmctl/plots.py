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
