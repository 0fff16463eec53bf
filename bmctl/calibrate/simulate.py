"""The stochastic plant as the simulator of a history, and the summaries compared with data.

A thin adapter over :class:`bmctl.plant.plant.Plant` (``Plant(card, rng, M)``,
``advance(rpm, hours, milling=...)``, arrays ``s`` in m and ``r``): the plant runs the
history's schedule and its whole population is read at each sample time.

Summaries of a sample at one time (the statistics the fit matches): mean and standard
deviation of ln s (s in um) and of the irregularity r = 1 - pi s / L (eqn 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..config import ModelCard
from .params import set_params

UM = 1e-6
SUMMARY_NAMES = ("ln_s_mean", "ln_s_std", "r_mean", "r_std")
BOOT_BLOCK = 1 << 22  # bootstrap indices drawn at once (bootstrap_cov)


def summaries(s_um: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(mean ln s, std ln s, mean r, std r) of one sample; s in um."""
    ls = np.log(np.asarray(s_um, dtype=float))
    r = np.asarray(r, dtype=float)
    return np.array([ls.mean(), ls.std(), r.mean(), r.std()])


def bootstrap_cov(s_um: np.ndarray, r: np.ndarray, rng: np.random.Generator, n_boot: int = 400) -> np.ndarray:
    """Sampling covariance (4 x 4) of :func:`summaries` for this sample (nonparametric bootstrap)."""
    n = s_um.size
    log_s, r = np.log(s_um), np.asarray(r, dtype=float)
    # resamples in blocks of about BOOT_BLOCK indices: a sample of a million particles would otherwise
    # hold n_boot x n indices and values at once (~13 GB); the generator's stream, and so every
    # resample, is the same whatever the block size
    rows = max(1, BOOT_BLOCK // max(n, 1))
    stats = []
    for k in range(0, n_boot, rows):
        idx = rng.integers(0, n, size=(min(rows, n_boot - k), n))
        ls, rr = log_s[idx], r[idx]
        stats.append(np.stack([ls.mean(1), ls.std(1), rr.mean(1), rr.std(1)], axis=1))
    return np.cov(np.concatenate(stats), rowvar=False)


def pieces(segments: Sequence[tuple[float, float, float]], t0: float, t1: float) -> list[tuple[float, float, float]]:
    """The (hours, rpm, milling) pieces of a schedule between t0 and t1 (h)."""
    out, start = [], 0.0
    for h, rpm, milling in segments:
        a, b = max(t0, start), min(t1, start + h)
        if b > a + 1e-12:
            out.append((b - a, float(rpm), float(milling)))
        start += h
    return out


def run_history(card: ModelCard, segments, times_h: Sequence[float], particles: int,
                rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Run the plant through a schedule; its population (s_um, r) at each sample time.

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm, milling)
    times_h : sequence of float
        Increasing sample times (h), within the schedule.
    particles : int
        Simulated particles M.
    rng : numpy.random.Generator

    Returns
    -------
    list of (s_um, r)
    """
    from ..plant.plant import Plant

    plant = Plant(card, rng, particles)
    out, t = [], 0.0
    for t_h in times_h:
        for hours, rpm, milling in pieces(segments, t, t_h):
            plant.advance(rpm, hours, milling=milling)
        t = t_h
        out.append((plant.s / UM, plant.r.copy()))
    return out


@dataclass(frozen=True)
class SimTask:
    """One plant run: the card (plain data), parameter values, a history's schedule and times."""

    card: dict
    values: tuple[tuple[str, float], ...]
    segments: tuple[tuple[float, float, float], ...]
    times_h: tuple[float, ...]
    particles: int
    keep: int = 0  # > 0: also return this many particles drawn from each population


def simulate_task(task: SimTask, rng: np.random.Generator):
    """Run one :class:`SimTask` (module level: Dask workers call it).

    Returns
    -------
    (summaries, samples)
        ``summaries``: array (times, 4); ``samples``: list of (s_um, r) of ``keep`` particles
        per time (empty when ``keep`` is 0).
    """
    card = set_params(ModelCard.model_validate(task.card), dict(task.values))
    pops = run_history(card, task.segments, task.times_h, task.particles, rng)
    S = np.array([summaries(s, r) for s, r in pops])
    kept = []
    if task.keep:
        for s, r in pops:
            k = rng.choice(s.size, size=min(task.keep, s.size), replace=False)
            kept.append((s[k], r[k]))
    return S, kept
