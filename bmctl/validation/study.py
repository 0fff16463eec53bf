"""Evidence for the particle filter: synthetic truth from the stochastic plant, off-card factors.

The truth is the stochastic PLANT (not the moment model) run on a copy of the card whose
bonding and fracture factors gamma and delta are off by a given ratio (e.g. gamma x1.3,
delta x0.7). At every sample time a micrograph sample of n particles is drawn from the
plant's population through the measurement path's sampler
(:func:`bmctl.measure.sampler.micrograph_sample`, segmentation noise 0.03 on area and
perimeter), and every filter variant (size law, n) is updated with it; all variants see the
same plant trajectory. The filter runs the moment model of the UNMODIFIED card.

What "truth" means:

* moments: the plant's population moments (s_mean, s_std, r_mean, r_std) at the sample time;
* parameters p = (gamma_mult, delta_mult), two readings, both reported: the truth, the
  plant's (gamma_plant / gamma_card, delta_plant / delta_card), and the model-optimal
  ("pseudo-true") parameters: those that make the moment model's
  trajectory from the card's initial state best match the plant's mean (s_mean, s_std)
  trajectory (least squares in log, on a grid). With a misspecified model the filter can at
  best converge to the latter.

Each sample interval is one open-loop step of :func:`bmctl.loop.run_interval` (the plant and
every filter through the same schedule pieces). Used by ``benchmarks/pf_study.py`` (full
study) and the estimation tests (a small one).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from ..config import ModelCard, load_card, with_factors
from ..loop import run_interval
from ..plant.plant import Plant
from ..plant.population import UM
from ..estimate.filter import FilterSettings, ParticleFilter
from ..estimate.likelihood import LawSettings
from ..schedule import Schedule, as_schedule

MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std")


@dataclass(frozen=True)
class Variant:
    """One filter configuration of the study: measured particles n, size law, optional overrides.

    ``settings`` and ``law`` are ``(name, value)`` pairs replacing FilterSettings and
    LawSettings fields (ablations); ``tag`` names them in the label.
    """

    n: int
    size_law: str = "weibull"
    tag: str = ""
    settings: tuple = ()
    law: tuple = ()

    @property
    def label(self) -> str:
        return f"{self.size_law}-n{self.n}" + (f"-{self.tag}" if self.tag else "")

    def filter_settings(self, base: FilterSettings, n_particles: int) -> FilterSettings:
        law = replace(base.law, size_law=self.size_law, **dict(self.law))
        return base.replace(n_particles=n_particles, law=law, **dict(self.settings))


#: the ablations of docs/estimation.md: the plain bootstrap filter with the untempered likelihood
#: (what collapsed), the guided proposal alone, and the default (guided + tempered)
UNTEMPERED = (("calibrate_learning_rate", False), ("learning_rate", 1.0))
NO_MISFIT = (("misfit", (0.0, 0.0, 0.0, 0.0)),)
ABLATION = (
    Variant(300, tag="bootstrap-untempered", settings=UNTEMPERED + (("proposal", "bootstrap"),), law=NO_MISFIT),
    Variant(300, tag="guided-untempered", settings=UNTEMPERED, law=NO_MISFIT),
    Variant(300),
)


@dataclass
class StudyConfig:
    """A study: card, off-card factor scenarios, seeds, recipe length, sampling and filter sizes."""

    card: str = "models/alni-1to1-300rpm-lab.toml"
    scenarios: tuple = ((1.3, 0.7), (0.7, 1.3))
    seeds: Sequence[int] = tuple(range(20))
    hours: float = 12.0
    every_h: float = 1.0
    plant_particles: int = 5000
    filter_particles: int = 1000
    variants: tuple = (Variant(50), Variant(100), Variant(300), Variant(300, "lognormal"))
    base: FilterSettings = field(default_factory=FilterSettings)


def run_one(model, card: ModelCard, scenario: tuple[float, float], seed: int, cfg: StudyConfig) -> dict:
    """One seeded run: plant truth and every variant's estimates at every sample time.

    Returns a dict of arrays: ``t_h`` (K,), ``truth`` (K, 6: the four moments, the
    temperature and the hardening), and per variant label ``mean``, ``q05``, ``q95`` (K, 8)
    and ``ess`` (K,).
    """
    from ..measure.sampler import micrograph_sample

    plant = Plant(with_factors(card, *scenario), np.random.default_rng([seed, 0]), cfg.plant_particles)
    schedule = Schedule.from_card(card, cfg.hours)
    times = np.arange(cfg.every_h, cfg.hours + 1e-9, cfg.every_h)
    filters = {}
    for k, v in enumerate(cfg.variants):
        st = v.filter_settings(cfg.base, cfg.filter_particles)
        filters[v] = ParticleFilter(model, np.random.default_rng([seed, 1, k]), st)
    sample_rng = {n: np.random.default_rng([seed, 2, n]) for n in sorted({v.n for v in cfg.variants})}
    out = {"t_h": times, "truth": np.zeros((times.size, 6))}
    for v in cfg.variants:
        out[v.label] = {"mean": np.zeros((times.size, 8)), "q05": np.zeros((times.size, 8)),
                        "q95": np.zeros((times.size, 8)), "ess": np.zeros(times.size)}
    t_prev = 0.0
    for i, t in enumerate(times):
        run_interval(plant, (), schedule, t_prev, t)
        mo = plant.moments()
        out["truth"][i] = [mo[m] for m in MOMENTS] + [mo["temperature_c"], mo["hardening"]]
        tabs = {n: micrograph_sample(plant.s / UM, plant.r, n, g) for n, g in sample_rng.items()}
        for v, pf in filters.items():
            run_interval(None, (pf,), schedule, t_prev, t)
            e = pf.update(tabs[v.n].s_um, tabs[v.n].r)
            rec = out[v.label]
            rec["mean"][i], rec["q05"][i], rec["q95"][i], rec["ess"][i] = e.mean, e.q05, e.q95, e.ess
        t_prev = t
    return out


def run_study(cfg: StudyConfig, progress=None) -> dict:
    """All runs of a study: ``{scenario: [run_one(...) for each seed]}``."""
    from ..moments.forcard import for_card

    model = for_card(cfg.card)  # refuses coefficients of another card
    card = load_card(cfg.card)
    res = {}
    for sc in cfg.scenarios:
        res[sc] = []
        for seed in cfg.seeds:
            res[sc].append(run_one(model, card, sc, seed, cfg))
            if progress is not None:
                progress(sc, seed)
    return res


def coverage(runs: list[dict], label: str) -> np.ndarray:
    """Share of (run, time) pairs whose 90 % interval holds the true moment, per moment (4,)."""
    hits = []
    for r in runs:
        tr = r["truth"][:, :4]
        lo, hi = r[label]["q05"][:, :4], r[label]["q95"][:, :4]
        hits.append((lo <= tr) & (tr <= hi))
    return np.mean(np.concatenate(hits), axis=0)


def log_errors(runs: list[dict], label: str) -> np.ndarray:
    """|ln(estimate mean / true moment)| for every (run, time) pair, per moment (R*K, 4)."""
    return np.concatenate([np.abs(np.log(r[label]["mean"][:, :4] / r["truth"][:, :4])) for r in runs])


def param_trajectory(runs: list[dict], label: str) -> dict:
    """Mean over runs of the multiplier estimates (and of their 90 % limits) at each time."""
    mean = np.mean([r[label]["mean"][:, 6:8] for r in runs], axis=0)
    q05 = np.mean([r[label]["q05"][:, 6:8] for r in runs], axis=0)
    q95 = np.mean([r[label]["q95"][:, 6:8] for r in runs], axis=0)
    return {"t_h": runs[0]["t_h"], "mean": mean, "q05": q05, "q95": q95}


def pseudo_true_multipliers(model, truth_mean: np.ndarray, segments, times, grid=None,
                            ridge: float = 0.01) -> np.ndarray:
    """Multipliers whose moment-model trajectory best fits the mean true (s_mean, s_std) path.

    Least squares of ln(model / truth) of s_mean and s_std over the sample times, the model
    run from its initial state under the schedule; minimised on a log grid (0.3 .. 4). The
    fit is flat along a ridge (raising both rates together changes little), so a weak
    penalty ``ridge * |ln p|^2`` picks the point of the ridge nearest the card (1, 1).
    """
    g = np.exp(np.linspace(np.log(0.3), np.log(4.0), 41)) if grid is None else np.asarray(grid)
    B, F = np.meshgrid(g, g, indexing="ij")
    P = np.stack([B.ravel(), F.ravel()], axis=1)
    X = np.repeat(model.x0()[None, :], P.shape[0], axis=0)
    J = np.zeros(P.shape[0])
    t_prev = 0.0
    for i, t in enumerate(times):
        for rpm, milling, h in as_schedule(segments).inputs_between(t_prev, t):
            X = model.step(X, np.array([rpm, milling]), h, P)
        e = np.log(X[:, :2] / truth_mean[i, :2][None, :])
        J += np.sum(e * e, axis=1)
        t_prev = t
    J += ridge * np.sum(np.log(P) ** 2, axis=1)
    return P[int(np.argmin(J))]


def law_misfit(card_path: str, scenarios=((1.0, 1.0), (1.3, 0.7), (0.7, 1.3)), times=(1, 3, 6, 9, 12),
               particles: int = 20000, measured: int = 20000, seed: int = 0) -> list[dict]:
    """Pseudo-true moments of each size law: the maximum of the filter's own (rastered) likelihood
    for a very large micrograph sample of the plant, against the plant's true moments.

    Returns one dict per (scenario, time): ``truth`` (4,) and, per size law, the fitted moments
    (4,). Their relative differences are the law-misfit floors of
    :data:`bmctl.estimate.likelihood.LAW_MISFIT`.
    """
    from ..measure.sampler import micrograph_sample
    from ..estimate.likelihood import SIZE_LAWS, Raster, fit_sample

    card = load_card(card_path)
    out = []
    for sc in scenarios:
        plant = Plant(with_factors(card, *sc), np.random.default_rng([seed, 3]), particles)
        rng = np.random.default_rng([seed, 4])
        t_prev = 0.0
        for t in times:
            plant.advance(card.process.rpm, t - t_prev)
            t_prev = t
            mo = plant.moments()
            tab = micrograph_sample(plant.s / UM, plant.r, measured, rng)
            row = {"scenario": sc, "t_h": t, "truth": np.array([mo[m] for m in MOMENTS])}
            for law_name in SIZE_LAWS:
                law = LawSettings(size_law=law_name)
                row[law_name] = np.exp(fit_sample(Raster.from_particles(tab.s_um, tab.r, law), law).z)
            out.append(row)
    return out
