"""A measured particle sample against the plant's predicted population at the same time.

The plant (:class:`bmctl.plant.plant.Plant`) runs the schedule up to ``at_h`` from one seeded
generator; its population (s, r) is compared with the measured table by two-sample tests on
s and on r: Kolmogorov-Smirnov (``scipy.stats.ks_2samp``) and k-sample Anderson-Darling
(``scipy.stats.anderson_ksamp``, p-value capped to [0.001, 0.25] by scipy). Sizes are compared
as measured, the plant's s being the paper's 2-D size (eqn 1) and r = 1 - pi s / L (eqn 3).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..errors import InputError
from ..naming import arg

UM = 1e-6


def truncate_schedule(segments, at_h: float) -> list[tuple[float, float]]:
    """The (hours, rpm) segments cut at ``at_h`` hours.

    Raises
    ------
    bmctl.errors.InputError
        ``at_h`` is negative or beyond the end of the schedule.
    """
    total = sum(h for h, _ in segments)
    if not 0.0 <= at_h <= total + 1e-9:
        raise InputError(f"{arg('at_h')}: must be in [0, {total:g}] h, the schedule's length (got {at_h:g})")
    out, done = [], 0.0
    for h, rpm in segments:
        take = min(h, at_h - done)
        if take <= 1e-12:
            break
        out.append((take, rpm))
        done += take
    return out


def predicted_population(card, segments, at_h: float, rng: np.random.Generator, particles: int | None = None):
    """The plant's population (s in um, r) after the schedule has run for ``at_h`` hours.

    Parameters
    ----------
    card : bmctl.config.ModelCard
    segments : sequence of (hours, rpm)
    at_h : float
    rng : numpy.random.Generator
    particles : int, optional
        Simulated particles M (default: the card's).

    Returns
    -------
    s_um, r : ndarray
    """
    from ..plant.plant import Plant

    plant = Plant(card, rng, particles)
    for h, rpm in truncate_schedule(segments, at_h):
        plant.advance(rpm, h)
    return plant.s / UM, plant.r.copy()


@dataclass(frozen=True)
class TwoSample:
    """Two-sample statistics of one quantity."""

    ks: float
    ks_p: float
    ad: float
    ad_p: float
    median_measured: float
    median_predicted: float

    def as_dict(self) -> dict:
        """JSON-ready dict."""
        return {k: float(v) for k, v in self.__dict__.items()}


def two_sample(measured, predicted) -> TwoSample:
    """KS and Anderson-Darling statistics (and p-values) of two samples.

    Parameters
    ----------
    measured, predicted : array_like
        1-D samples (at least 2 values each).

    Returns
    -------
    TwoSample
    """
    a, b = np.asarray(measured, float), np.asarray(predicted, float)
    if a.size < 2 or b.size < 2:
        raise InputError(f"compare: need at least 2 particles on each side (got {a.size} and {b.size})")
    ks = stats.ks_2samp(a, b)
    with warnings.catch_warnings():  # scipy warns when it caps the AD p-value
        warnings.simplefilter("ignore")
        ad = stats.anderson_ksamp([a, b])
    return TwoSample(float(ks.statistic), float(ks.pvalue), float(ad.statistic), float(ad.pvalue),
                     float(np.median(a)), float(np.median(b)))


def compare_figure(path, s_meas, r_meas, s_pred, r_pred, *, title: str = "") -> None:
    """Histograms of s (log axis, µm; density per ln s, which a log axis shows undistorted) and
    r, measured against predicted, as a PNG (atomic)."""
    from ..io import pyplot, savefig
    from ..plots import log_size_axis

    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    lo = max(min(np.min(s_meas), np.min(s_pred)), 1e-3)
    hi = max(np.max(s_meas), np.max(s_pred))
    edges = np.geomspace(lo, hi * 1.0001, 31)
    dln = float(np.log(edges[1] / edges[0]))
    per_ln = lambda s: np.full(len(s), 1.0 / (len(s) * dln))  # noqa: E731  (bar height = density per ln s)
    ax1.hist(s_pred, bins=edges, weights=per_ln(s_pred), alpha=0.5, label=f"plant prediction (M = {len(s_pred)})")
    ax1.hist(s_meas, bins=edges, weights=per_ln(s_meas), histtype="step", lw=2, color="k",
             label=f"measured (n = {len(s_meas)})")
    ax1.set_xscale("log")
    log_size_axis(ax1)
    ax1.set_xlabel("size s = 2√(A/π) (µm, log scale)")
    ax1.set_ylabel("density per ln s (by number)")
    ax1.legend(fontsize=8)
    r_edges = np.linspace(0.0, max(float(np.max(r_meas)), float(np.max(r_pred)), 0.05) * 1.0001, 31)
    ax2.hist(r_pred, bins=r_edges, density=True, alpha=0.5, label="plant prediction")
    ax2.hist(r_meas, bins=r_edges, density=True, histtype="step", lw=2, color="k", label="measured")
    ax2.set_xlabel("irregularity r = 1 − πs/L")
    ax2.set_ylabel("density per unit r (by number)")
    ax2.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    savefig(fig, path, dpi=120)
