"""The simulated-particle sample: raster p(s, r), moments, initial powder.

The sample of M particles stands for the vial's population (constant-number Monte
Carlo, docs/model.md); every simulated particle carries the same weight, so number
fractions are plain sample fractions.
"""

from __future__ import annotations


import numpy as np

from ..stats import SIZE_STAT_NAMES, gaussian_smooth, size_stats

UM = 1e-6  # metres per micrometre
DS_UM = 1.0  # paper's stochastic raster: Delta s = 1 um
DR = 0.01  # Delta r = 0.01
MODE_SMOOTH_BINS = 2.0  # Gaussian smoothing (in raster bins) before taking the mode

MOMENT_NAMES = ("s_mean_um", "s_std_um", "s_mode_um", "r_mean", "r_std", "r_mode")  # number-weighted
WEIGHTED_NAMES = SIZE_STAT_NAMES  # d10/d50/d90/span by volume, mean/mode by area (bmctl.stats)


def raster_edges(s_max_um: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """Bin edges of the paper's (s, r) raster: s in um (step 1), r (step 0.01)."""
    s_edges = np.arange(0.0, s_max_um + DS_UM / 2, DS_UM)
    r_edges = np.linspace(0.0, 1.0, int(round(1 / DR)) + 1)
    return s_edges, r_edges


def raster(s_m: np.ndarray, r: np.ndarray, s_max_um: float = 1000.0) -> np.ndarray:
    """Population fractions p(s, r) on the raster; sizes beyond ``s_max_um`` go to the last bin."""
    s_edges, r_edges = raster_edges(s_max_um)
    ns, nr = s_edges.size - 1, r_edges.size - 1
    i = np.clip((s_m / UM / DS_UM).astype(np.int64), 0, ns - 1)
    j = np.clip((r / DR).astype(np.int64), 0, nr - 1)
    counts = np.bincount(i * nr + j, minlength=ns * nr).reshape(ns, nr)
    return counts / max(s_m.size, 1)


def _mode(values: np.ndarray, step: float, lo: float, hi: float) -> float:
    n = int(np.ceil((hi - lo) / step))
    idx = np.clip(((values - lo) / step).astype(np.int64), 0, n - 1)
    h = np.bincount(idx, minlength=n).astype(float)
    h = gaussian_smooth(h, MODE_SMOOTH_BINS)
    return lo + (np.argmax(h) + 0.5) * step


def moments(s_m: np.ndarray, r: np.ndarray, s_cap_um: float = 1e4) -> dict[str, float]:
    """Number-weighted mean, std and mode of s (um) and r, plus weighted size statistics.

    The mode is the centre of the most populated raster bin after a Gaussian
    smoothing of ``MODE_SMOOTH_BINS`` bins (the raw 1-um raster is too noisy for M ~ 1e4).
    The keys of :data:`MOMENT_NAMES` are number-weighted; those of :data:`SIZE_STAT_NAMES`
    are volume-weighted D-values and span, and the area-weighted mean and mode
    (:func:`bmctl.stats.size_stats`).
    """
    s_um = s_m / UM
    out = {
        "s_mean_um": float(s_um.mean()),
        "s_std_um": float(s_um.std()),
        "s_mode_um": float(_mode(s_um, DS_UM, 0.0, float(np.clip(s_um.max() + 1.0, 2.0, s_cap_um)))),
        "r_mean": float(r.mean()),
        "r_std": float(r.std()),
        "r_mode": float(_mode(r, DR, 0.0, 1.0)),
    }
    out.update(size_stats(s_um))
    return out


def initial_sample(rng: np.random.Generator, n: int, s_mean_um: float, s_std_um: float, r_mean: float):
    """Initial powder: Gaussian size (truncated at 10 % of the mean), exponential small r.

    Returns s (m) and r arrays of length ``n``.
    """
    s = rng.normal(s_mean_um, s_std_um, size=n)
    lo = 0.1 * s_mean_um
    bad = s < lo
    while bad.any():
        s[bad] = rng.normal(s_mean_um, s_std_um, size=int(bad.sum()))
        bad = s < lo
    r = np.minimum(rng.exponential(r_mean, size=n), 0.5) if r_mean > 0 else np.zeros(n)
    return s * UM, r
