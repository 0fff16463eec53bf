"""Run an estimator (particle filter or UKF) over a sequence of samples under a schedule; write the CSV and figure.

Shared by ``bmctl estimate`` and the evidence study (:mod:`bmctl.validation.study`).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError, require_generator
from .filter import (N_PARTICLES_MIN, READING_MIN_C, Estimate, FilterSettings, ParticleFilter,  # noqa: F401
                     check_reading)
from .likelihood import S_RANGE_UM, check_particles  # noqa: F401

ESTIMATORS = ("pf", "ukf")


def make_estimator(kind: str, model, rng: np.random.Generator, n_particles: int | None = None, law=None,
                   settings=None):
    """A fresh estimator of the given kind on ``model``.

    Parameters
    ----------
    kind : {"pf", "ukf"}
        Particle filter or unscented Kalman filter.
    model : MomentModel
        The estimator's model.
    rng : numpy.random.Generator
        The estimator's generator (the UKF draws nothing).
    n_particles : int, optional
        Particles of the particle filter (ignored by the UKF).
    law : LawSettings, optional
        Measurement laws (default: the settings' default).
    settings : FilterSettings or UKFSettings, optional
        Full settings (``n_particles`` and ``law`` then ignored).

    Returns
    -------
    ParticleFilter or UKFEstimator
    """
    if kind not in ESTIMATORS:
        raise InputError(f"kind: the estimator is one of {', '.join(ESTIMATORS)} (got {kind!r})")
    require_generator(rng, "rng")  # the UKF draws nothing, but takes the generator it is given alike
    if n_particles is not None and (isinstance(n_particles, bool) or not isinstance(n_particles, numbers.Real)
                                    or not float(n_particles).is_integer()):
        raise InputError(f"n_particles: a whole number of particles (got {n_particles!r})")
    if kind == "pf" and settings is None and n_particles is not None and n_particles < N_PARTICLES_MIN:
        raise InputError(f"n_particles: the particle filter needs {N_PARTICLES_MIN} or more particles "
                         f"(got {n_particles!r})")
    if kind == "ukf":
        from .ukf import UKFEstimator, UKFSettings  # filterpy (scipy.stats) only when a UKF is asked for

        if settings is None:
            settings = UKFSettings() if law is None else UKFSettings(law=law)
        return UKFEstimator(model, rng, settings)
    if settings is None:
        kw = {} if n_particles is None else {"n_particles": int(n_particles)}
        if law is not None:
            kw["law"] = law
        settings = FilterSettings(**kw)
    return ParticleFilter(model, rng, settings)


@dataclass
class Sample:
    """One measured sample: particle sizes (um), aspect ratios, optional vial temperature.

    Attributes
    ----------
    t_h : float
        Milling time of the sample (h).
    s_um, r : ndarray
        Measured sizes (um) and aspect ratios.
    temperature_c : float, optional
        Vial-temperature reading.
    source : str
        Where the sample came from (file name), for messages.
    """

    t_h: float
    s_um: np.ndarray
    r: np.ndarray
    temperature_c: float | None = None
    source: str = ""


#: an update whose effective sample size falls below this has collapsed onto (about) one particle
ESS_COLLAPSED = 1.5


def check_sample(smp: "Sample") -> "Sample":
    """Refuse a sample with no particles, a size outside S_RANGE_UM or r outside [0, 1); returns it."""
    from ..errors import InputError

    s, r = np.asarray(smp.s_um, dtype=float), np.asarray(smp.r, dtype=float)
    where = smp.source or f"sample at {smp.t_h:g} h"
    check_particles(s, r, where)
    if smp.temperature_c is not None and not math.isfinite(smp.temperature_c):
        raise InputError(f"{where}: temperature reading must be finite")
    return smp


def collapsed(est: Estimate) -> bool:
    """Whether an update was degenerate: every particle impossible, or the ESS collapsed to ~1."""
    return bool(est.degenerate or est.ess < ESS_COLLAPSED)


def inputs_between(segments: Sequence[tuple[float, float]], t0: float, t1: float) -> list[tuple[float, float, float]]:
    """The (rpm, milling, hours) pieces of a (hours, rpm) schedule between t0 and t1.

    Time beyond the end of the schedule is a rest (rpm 0). ``milling`` is 1 for rpm > 0
    (:meth:`bmctl.schedule.Schedule.inputs_between`).
    """
    from ..schedule import as_schedule

    return as_schedule(segments).inputs_between(t0, t1)


def run_filter(model, samples: Sequence[Sample], segments: Sequence[tuple[float, float]],
               settings: FilterSettings | UKFSettings | None = None, seed: int = 0, max_step_h: float = 1.0,
               pf=None, progress=None) -> tuple[ParticleFilter | UKFEstimator, list[Estimate]]:
    """Filter the samples in time order; returns the filter and one estimate per sample.

    Between samples the filter predicts under the schedule's inputs in pieces of at most
    ``max_step_h`` hours.

    Parameters
    ----------
    model : MomentModel
        The filter's model.
    samples : sequence of Sample
        In increasing time, from 0 h (or from the time ``pf`` has reached); else refused.
    segments : sequence of (hours, rpm)
        The schedule from t = 0 (rpm 0: rest; beyond its end: rest).
    settings : FilterSettings or UKFSettings, optional
        Their type picks the estimator (default: the particle filter's defaults).
    seed : int, optional
        Seed of the filter's generator (ignored when ``pf`` is given).
    max_step_h : float, optional
        Longest single predict step (h), a finite number > 0.
    pf : ParticleFilter or UKFEstimator, optional
        Continue this filter instead of starting a new one.
    progress : callable, optional
        Called with the hours of each predict step once it is done (e.g. ``tqdm.update``).

    Returns
    -------
    (ParticleFilter or UKFEstimator, list of Estimate)

    Raises
    ------
    InputError
        A sample out of time order or before the filter's time, a bad sample or reading, or a
        ``max_step_h`` that is not a finite number of hours > 0: before any work.
    """
    from ..errors import InputError
    from ..loop import positive_hours
    from ..physics.constants import TIME_EPS_H

    positive_hours(max_step_h, "max_step_h")
    t_prev = None if pf is None else float(pf.t_h)
    for k, smp in enumerate(samples):
        where = smp.source or f"sample[{k}]"
        t = smp.t_h
        if isinstance(t, bool) or not isinstance(t, numbers.Real) or not math.isfinite(t) or t < 0:
            raise InputError(f"{where}: t_h must be a finite number of hours >= 0 (got {t!r})")
        if t_prev is not None and (t < t_prev - TIME_EPS_H if k == 0 else t <= t_prev):
            raise InputError(f"{where}: t_h: sample times must increase (got {t_prev:g} then {t:g})"
                             if k else f"{where}: t_h: {t:g} h is before the filter's time, {t_prev:g} h")
        t_prev = float(t)
    if pf is None:
        from .ukf import UKFSettings

        kind = "ukf" if isinstance(settings, UKFSettings) else "pf"
        pf = make_estimator(kind, model, np.random.default_rng(seed), settings=settings)
    for smp in samples:  # bad input is refused before any work, naming the sample
        check_sample(smp)
        check_reading(model.card, smp.temperature_c, smp.source or f"sample at {smp.t_h:g} h")
    out = []
    for smp in samples:
        for rpm, milling, hours in inputs_between(segments, pf.t_h, smp.t_h):
            k = max(1, int(np.ceil(hours / max_step_h - 1e-9)))
            for _ in range(k):
                pf.predict((rpm, milling), hours / k)
                if progress is not None:
                    progress(hours / k)
        pf.t_h = smp.t_h  # no drift from summing pieces
        out.append(pf.update(smp.s_um, smp.r, smp.temperature_c))
    return pf, out


def estimate_rows(estimates: Sequence[Estimate]) -> tuple[list[str], list[list]]:
    """CSV header and rows: t_h, n_measured, ess, resampled, degenerate (:func:`collapsed`), eta_size,
    eta_shape, then mean/q05/q95 of every state and parameter, then of the size statistics
    (volume-weighted D-values and span, area-weighted mean and mode) where every estimate has them."""
    names = estimates[0].names
    stats = [k for k in estimates[0].size_stats if all(k in e.size_stats for e in estimates)]
    header = ["t_h", "n_measured", "ess", "resampled", "degenerate", "eta_size", "eta_shape"]
    for n in list(names) + stats:
        header += [n, f"{n}_q05", f"{n}_q95"]
    rows = []
    for e in estimates:
        row = [float(e.t_h), int(e.n_measured), float(e.ess), int(e.resampled), int(collapsed(e)), float(e.eta[0]),
               float(e.eta[1])]
        for k in range(len(names)):
            row += [float(e.mean[k]), float(e.q05[k]), float(e.q95[k])]
        for k in stats:
            row += [float(v) for v in e.size_stats[k]]
        rows.append(row)
    return header, rows


def plot_estimates(path: str | Path, estimates: Sequence[Estimate], samples: Sequence[Sample] | None = None,
                   title: str = "", truth: dict | None = None) -> None:
    """Mean and 90 % band of every state and parameter over time; the raw sample moments as dots.

    The time axis runs from 0 (the start of the schedule) to the last time drawn. Where the estimates
    stand at a single time (one sample), a band has no width: the 90 % interval is drawn as error bars.
    """
    from ..io import pyplot, savefig

    from ..plots import quantity_label

    plt = pyplot()

    names = estimates[0].names
    t = np.array([e.t_h for e in estimates])
    mean = np.array([e.mean for e in estimates])
    lo = np.array([e.q05 for e in estimates])
    hi = np.array([e.q95 for e in estimates])
    one_time = np.unique(t).size < 2
    raw = {}
    if samples is not None:
        raw = {"s_mean_um": [np.mean(s.s_um) for s in samples], "s_std_um": [np.std(s.s_um) for s in samples],
               "r_mean": [np.mean(s.r) for s in samples], "r_std": [np.std(s.r) for s in samples]}
        if all(s.temperature_c is not None for s in samples):
            raw["temperature_c"] = [s.temperature_c for s in samples]
    t_end = float(max([t.max()] + ([np.max(truth.get("t_h", t))] if truth else [])))
    t_end = t_end if t_end > 0 else 1.0
    ncol = 4
    nrow = int(np.ceil(len(names) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.7 * nrow + 0.4), squeeze=False, layout="constrained")
    for k, name in enumerate(names):
        ax = axes.flat[k]
        if one_time:
            err = np.clip([mean[:, k] - lo[:, k], hi[:, k] - mean[:, k]], 0.0, None)
            ax.errorbar(t, mean[:, k], yerr=err, fmt="o", color="tab:blue", ms=4, capsize=4, lw=1.2,
                        label="filter mean, 90 % interval")
        else:
            ax.fill_between(t, lo[:, k], hi[:, k], color="tab:blue", alpha=0.25, lw=0, label="90 % interval")
            ax.plot(t, mean[:, k], color="tab:blue", marker="o", ms=3, lw=1.2, label="filter mean")
        if name in raw:
            ax.plot(t, raw[name], ls="none", marker="x", color="k", ms=4, label="sample moment")
        if truth and name in truth:
            ax.plot(truth.get("t_h", t), truth[name], color="tab:red", lw=1.0, label="truth")
        ax.set_title(quantity_label(name), fontsize=8)
        ax.set_xlabel("t (h)", fontsize=8)
        ax.set_xlim(-0.03 * t_end, 1.03 * t_end)  # from 0; markers at 0 and at the end show whole
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    handles = {}
    for ax in axes.flat[:len(names)]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    first = ("filter mean, 90 % interval", "90 % interval", "filter mean")  # the filter, then the data
    handles = {lab: handles[lab] for lab in sorted(handles, key=lambda x: x not in first)}
    fig.legend(list(handles.values()), list(handles), loc="outside lower center", ncol=len(handles), fontsize=7,
               frameon=False)
    ax = axes.flat[len(names)] if len(names) < nrow * ncol else None
    if ax is not None:
        ax.plot(t, [e.ess for e in estimates], marker="o", ms=3, color="tab:green")
        ax.set_title("effective sample size after update", fontsize=8)
        ax.set_ylabel("particles", fontsize=8)
        ax.set_xlabel("t (h)", fontsize=8)
        ax.set_xlim(-0.03 * t_end, 1.03 * t_end)
        ax.grid(alpha=0.3)
    for extra in list(axes.flat)[len(names) + 1:]:
        extra.axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    savefig(fig, path, dpi=110)
