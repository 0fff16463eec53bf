"""Checks of the plant engine on the model cards: the impact loop's energetics, the batched
plant against the one-collision-at-a-time reference, and bookkeeping in long runs.

See :mod:`bmctl.validation` and docs/verification.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from ..config import ModelCard
from ..plant import events as ev
from ..plant.kernels import dissipation_coefficients
from ..plant.plant import Plant
from .exact import BIAS_ALPHA, Z_BIAS
from .cases import Run, family_p

# --- the loop "until Delta U is spent" against the plant's impact sampler ----------------------

@dataclass
class Energetics:
    """Impacts of the literal loop (Sec. 3.2-3.3) against the plant's sampler, on a frozen sample.

    ``rate_*``: processings per particle per second; ``plastic_*``: mean plastic share
    cos^2(2 psi) of an impact; ``u_in_*``: mean U_in of an impact (J); each with its standard
    error over the loop's collisions (the plant's values are exact or from a large sample).
    ``rate_wald`` counts each collision's impacts without its overshoot, K - (S_K - Delta U) / mu
    (S_K: heat of its K impacts, mu: mean heat of an impact at its U_in and psi); by Wald's
    identity its mean is E[Delta U / mu], the plant's expected count. ``overshoot`` is the
    mean of (S_K - Delta U) / mu, the impacts a collision runs past its budget.
    """

    rate_loop: float
    rate_loop_se: float
    rate_wald: float
    rate_wald_se: float
    overshoot: float
    rate_plant: float
    plastic_loop: float
    plastic_loop_se: float
    plastic_plant: float
    u_in_loop: float
    u_in_loop_se: float
    u_in_plant: float
    steps_per_collision: float

    def z(self) -> dict[str, float]:
        """z-scores of loop minus plant."""
        return {
            "rate": (self.rate_wald - self.rate_plant) / self.rate_wald_se,
            "plastic": (self.plastic_loop - self.plastic_plant) / self.plastic_loop_se,
            "u_in": (self.u_in_loop - self.u_in_plant) / self.u_in_loop_se,
        }


def _ratio_se(num: np.ndarray, den: np.ndarray) -> tuple[float, float]:
    """Ratio of sums and its delta-method standard error over independent units."""
    r = num.sum() / den.sum()
    n = num.size
    resid = num - r * den
    return float(r), float(math.sqrt(n / (n - 1) * np.sum(resid**2)) / den.sum())


def energetics(card: ModelCard, rpm: float, collisions: int, seed: int, particles: int = 4000) -> Energetics:
    """Count the impacts of ``collisions`` collisions of the literal loop on a frozen initial sample.

    Each collision draws U_in > U_out from (5) (unweighted) and one psi; impacts on pairs
    picked uniformly, with zeta and xi per particle, dissipate e (sin^2 2psi (1 - zeta^2)
    + cos^2 2psi (1 - xi^2)) each (7), (8), e = U_in min(s^2 / (F_t X), 1) (6), until
    Delta U = U_in - U_out is spent (10). The population does not change (events are left
    out), so what is compared is the loop's stopping rule against the plant's hit rate
    and its weighting of U_in and psi.

    Parameters
    ----------
    card : ModelCard
        The model card.
    rpm : float
        Sun-disc speed.
    collisions : int
        Collisions of the loop.
    seed : int
        Seed of the sample and the draws.
    particles : int, optional
        Size of the frozen sample.
    """
    from ..physics.kinematics import kinematics

    rng = np.random.default_rng(seed)
    plant = Plant(card, rng, particles)
    kin = kinematics(card, rpm)
    st = card.stochastic
    x = plant.s**2
    N = plant.represented_particles
    e_share = np.minimum(x / (kin.trapped_fraction * plant.total_area), 1.0)
    ca, cb = dissipation_coefficients(st.alpha, st.beta)
    steps = np.empty(collisions)
    over = np.empty(collisions)
    plastic = np.empty(collisions)
    u_in_all = np.empty(collisions)
    for c in range(collisions):
        u_in, u_out = ev.sample_impact_energies(rng, kin.energy_scale, 1, weighted=False)  # (5)
        psi = rng.uniform(-np.pi / 2, np.pi / 2)
        budget = float(u_in[0] - u_out[0])
        k, spent = 0, 0.0
        while spent < budget:
            block = 64 + 2 * k
            e = u_in[0] * e_share[rng.integers(0, x.size, size=(block, 2))]
            zeta = ev.sample_zeta(rng, st.alpha, (block, 2))  # (9)
            xi = ev.sample_xi(rng, st.beta, (block, 2))
            dud = (ev.friction_heat(e, psi, zeta) + ev.plastic_heat(e, psi, xi)).sum(axis=1)  # (7), (8), (10)
            cum = spent + np.cumsum(dud)
            done = np.flatnonzero(cum >= budget)
            if done.size:
                k += int(done[0]) + 1
                spent = float(cum[done[0]])
                break
            k += block
            spent = float(cum[-1])
        mu = 2 * u_in[0] * e_share.mean() * (ca * math.sin(2 * psi) ** 2 + cb * math.cos(2 * psi) ** 2)
        steps[c] = k
        over[c] = (spent - budget) / mu
        plastic[c] = math.cos(2 * psi) ** 2
        u_in_all[c] = u_in[0]
    ones = np.ones(collisions)
    f_over_n = kin.frequency / N
    rate, rate_se = _ratio_se(2 * steps * f_over_n, ones)
    wald, wald_se = _ratio_se(2 * (steps - over) * f_over_n, ones)
    pl, pl_se = _ratio_se(steps * plastic, steps)
    ui, ui_se = _ratio_se(steps * u_in_all, steps)
    # the plant's sampler: its hit rate, and a large sample of its impacts
    big = 400_000
    u_p = plant.kernels.sample_energies(rng, kin.energy_scale, big)
    cos2psi_p = plant.kernels.sample_cos2psi(plant, rng, big)
    return Energetics(rate, rate_se, wald, wald_se, float(over.mean()), plant.hit_rate(kin), pl, pl_se, float(np.mean(cos2psi_p**2)),
                      ui, ui_se, float(u_p.mean()), float(steps.mean()))


# --- the batched plant against the one-collision-at-a-time reference ----------------------------

REFERENCE_MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "n_ratio")


@dataclass
class ReferenceComparison:
    """Final states of the plant and the reference over seeds, with the tests' verdicts.

    ``z``: Welch z-scores of the seed means (plant minus reference) of ``REFERENCE_MOMENTS``
    (n_ratio = N(t) / N(0)); ``ks_s``, ``ks_r``: two-sample Kolmogorov distance of the pooled
    final s and r, with p-values from the effective sample sizes (pooled size over the design
    effect of the runs, see :func:`design_effect`).
    """

    card: str
    hours: float
    particles: int
    seeds: tuple[int, ...]
    plant: dict[str, np.ndarray]
    reference: dict[str, np.ndarray]
    plant_s: list[np.ndarray]
    plant_r: list[np.ndarray]
    ref_s: list[np.ndarray]
    ref_r: list[np.ndarray]
    z: dict[str, float] = field(default_factory=dict)
    df: dict[str, float] = field(default_factory=dict)
    ks: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def moments_p(self) -> float:
        """Bonferroni-adjusted p-value of the most extreme moment z-score (Welch t)."""
        return family_p(self.z, self.df)

    @property
    def passed(self) -> bool:
        return self.moments_p > BIAS_ALPHA and all(p > KS_ALPHA for _, p in self.ks.values())


KS_ALPHA = 1e-3  # a two-sample KS p-value below this fails


def design_effect(samples: Sequence[np.ndarray], grid: np.ndarray) -> float:
    """Variance of a run's empirical CDF over the binomial variance, largest over ``grid`` (>= 1).

    Particles of one run are not independent (common history, resampling copies); pooling
    runs counts each particle as 1/deff of an independent draw.

    Parameters
    ----------
    samples : sequence of ndarray
        One sample per run.
    grid : ndarray
        Points where the CDFs are compared.
    """
    F = np.array([np.searchsorted(np.sort(x), grid, side="right") / x.size for x in samples])
    m = np.mean([x.size for x in samples])
    Fbar = F.mean(axis=0)
    binom = Fbar * (1 - Fbar)
    ok = binom > 1e-3
    if not ok.any() or len(samples) < 2:
        return 1.0
    return float(max(1.0, np.max(F[:, ok].var(axis=0, ddof=1) * m / binom[ok])))


def ks_clustered(a: Sequence[np.ndarray], b: Sequence[np.ndarray]) -> tuple[float, float]:
    """Two-sample Kolmogorov distance of pooled runs and its p-value with effective sample sizes.

    Parameters
    ----------
    a, b : sequence of ndarray
        The runs of each group.
    """
    pa, pb = np.concatenate(a), np.concatenate(b)
    d = float(stats.ks_2samp(pa, pb).statistic)
    grid = np.quantile(np.concatenate([pa, pb]), np.linspace(0.05, 0.95, 19))
    na = pa.size / design_effect(a, grid)
    nb = pb.size / design_effect(b, grid)
    return d, float(stats.kstwobign.sf(d * math.sqrt(na * nb / (na + nb))))


def _final_moments(s: np.ndarray, r: np.ndarray, n_ratio: float) -> list[float]:
    from ..plant.population import moments as pop_moments

    m = pop_moments(s, r)
    return [m["s_mean_um"], m["s_std_um"], m["r_mean"], m["r_std"], n_ratio]


def compare_reference(card: ModelCard, hours: float, particles: int, seeds: Sequence[int],
                      budget_scale: float = 1.0, progress: Callable[[str], None] | None = None) -> ReferenceComparison:
    """Run the plant and the reference from the same card for ``hours`` of the card's recipe, over seeds.

    Each seed gives both an independent run (different streams). Moments of the final s (um),
    r and N(t)/N(0) are compared by Welch z-scores of their seed means; the pooled final s
    and r by two-sample KS tests that allow for the runs' clustering.

    Parameters
    ----------
    card : ModelCard
        The model card (its recipe, :meth:`bmctl.schedule.Schedule.from_card`).
    hours : float
        Length of the runs (h).
    particles : int
        Simulated particles of both (the reference's initial sample).
    seeds : sequence of int
        Seeds.
    budget_scale : float, optional
        The reference's ``budget_scale``.
    progress : callable, optional
        Called with a line per seed.
    """
    from ..plant.reference import ReferencePlant
    from ..schedule import Schedule

    segments = Schedule.from_card(card, hours).pairs()
    P, R = [], []
    ps, pr, rs, rr = [], [], [], []
    for seed in seeds:
        if progress:
            progress(f"{card.card.name}: seed {seed}")
        plant = Plant(card, np.random.default_rng([seed, 1]), particles)
        n0 = plant.represented_particles
        ref = ReferencePlant(card, np.random.default_rng([seed, 2]), particles, budget_scale)
        m0 = ref.represented_particles
        for h, rpm in segments:
            plant.advance(rpm, h)
            ref.advance(rpm, h)
        s_ref, r_ref = ref.arrays()
        P.append(_final_moments(plant.s, plant.r, plant.represented_particles / n0))
        R.append(_final_moments(s_ref, r_ref, ref.represented_particles / m0))
        ps.append(plant.s / 1e-6)
        pr.append(plant.r.copy())
        rs.append(s_ref / 1e-6)
        rr.append(r_ref)
    P, R = np.array(P), np.array(R)
    res = ReferenceComparison(card.card.name, hours, particles, tuple(seeds),
                              dict(zip(REFERENCE_MOMENTS, P.T)), dict(zip(REFERENCE_MOMENTS, R.T)), ps, pr, rs, rr)
    for k in REFERENCE_MOMENTS:
        a, b = res.plant[k], res.reference[k]
        va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
        se = math.sqrt(va + vb)
        res.z[k] = float((a.mean() - b.mean()) / se) if se > 0 else 0.0
        res.df[k] = float((va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))) if se > 0 else 1.0
    res.ks["s"] = ks_clustered(ps, rs)
    res.ks["r"] = ks_clustered(pr, rr)
    return res


# --- bookkeeping in long runs ---------------------------------------------------------------------

class AuditedPlant(Plant):
    """A plant that checks every round of impacts: area conservation and the number balance.

    Before each round it notes sum(s^2); when the round's events are written (before the
    constant-number step) the area of the sample plus the fragments still to place must be
    the same, to rounding (eqns 2, 18, 20). Around the constant-number step it records
    log N_after - log(N_before (M - B + F) / M): zero in expectation (uniform copies and
    victims), with variance n_ops var(s^2) / sum(s^2)^2.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.area_err = 0.0  # largest |relative change| of the sample's area in the events of a round
        self.log_n_drift = 0.0  # sum of log N_after - log(N_before (M - B + F) / M)
        self.log_n_var = 0.0
        self.rounds = 0

    def _impact_round(self, kin, i, j, v):
        self._area_before = float(np.square(self.s).sum())
        self._n_before = self.represented_particles
        super()._impact_round(kin, i, j, v)

    def _rebalance(self, free, s_new, r_new, src, dst):
        area_events = float(np.square(self.s).sum() - np.square(self.s[free]).sum() + np.square(s_new).sum())
        self.area_err = max(self.area_err, abs(area_events / self._area_before - 1.0))
        M, B, F = self.M, free.size, s_new.size
        super()._rebalance(free, s_new, r_new, src, dst)
        x = np.square(self.s)
        self.log_n_drift += math.log(self.represented_particles / (self._n_before * (M - B + F) / M))
        self.log_n_var += abs(B - F) * float(x.var()) / float(x.sum()) ** 2
        self.rounds += 1


@dataclass
class Bookkeeping:
    """Checks of one long run.

    ``area_err``: largest relative change of the sample's area in the events of one round;
    ``total_area_err``: |w sum(s^2) / X - 1| at the end; ``n_z``: z-score of the drift of
    log N from the event balance; ``impacts_z``: z-score of the impact count against
    the hit rate (Poisson); ``s_min``, ``r_min``, ``r_max``: extremes over the run's checkpoints.
    """

    card: str
    hours: float
    particles: int
    area_err: float
    total_area_err: float
    n_z: float
    impacts_z: float
    s_min: float
    r_min: float
    r_max: float
    counts: tuple[int, int, int]
    rounds: int

    @property
    def passed(self) -> bool:
        return (self.area_err < 1e-12 and self.total_area_err < 1e-12 and abs(self.n_z) < Z_BIAS
                and abs(self.impacts_z) < Z_BIAS and self.s_min > 0 and self.r_min >= 0 and self.r_max < 1)


LONG_SCHEDULE = ((12.0, None), (2.0, 0.0), (12.0, "max"), (4.0, 0.0), (18.0, "mid"))  # 48 h


def long_schedule(card: ModelCard, scale: float = 1.0):
    """48 h (times ``scale``): the card's rpm, a rest, rpm_max, a rest, the mid speed.

    Parameters
    ----------
    card : ModelCard
        Supplies the rpm and rpm_max.
    scale : float, optional
        Factor on every segment's length.

    Returns
    -------
    Schedule
    """
    from ..schedule import Schedule

    out = []
    for h, rpm in LONG_SCHEDULE:
        speed = card.process.rpm if rpm is None else card.mill.rpm_max if rpm == "max" else \
            0.5 * (card.process.rpm + card.mill.rpm_max) if rpm == "mid" else rpm
        out.append((h * scale, float(speed)))
    return Schedule.from_pairs(out, "long")


def bookkeeping(card: ModelCard, particles: int, seed: int, scale: float = 1.0) -> Bookkeeping:
    """Run :func:`long_schedule` on an :class:`AuditedPlant`; conservation, balance and invariants.

    Parameters
    ----------
    card : ModelCard
        The model card.
    particles : int
        Simulated particles.
    seed : int
        Seed of the plant.
    scale : float, optional
        Factor on the schedule's length.
    """
    from ..physics.kinematics import kinematics

    plant = AuditedPlant(card, np.random.default_rng(seed), particles)
    X = plant.total_area
    expected = 0.0
    s_min, r_min, r_max = float(plant.s.min()), float(plant.r.min()), float(plant.r.max())
    for h, rpm in long_schedule(card, scale):
        steps = max(1, int(math.ceil(h)))
        for _ in range(steps):
            plant.advance(rpm, h / steps)
            s_min = min(s_min, float(plant.s.min()))
            r_min, r_max = min(r_min, float(plant.r.min())), max(r_max, float(plant.r.max()))
        expected += plant.hit_rate(kinematics(card, rpm)) * plant.M * h * 3600.0 / 2.0
    c = plant.counts
    return Bookkeeping(
        card.card.name, sum(h for h, _ in long_schedule(card, scale)), particles,
        plant.area_err, abs(plant.weight * float(np.square(plant.s).sum()) / X - 1.0),
        plant.log_n_drift / math.sqrt(plant.log_n_var) if plant.log_n_var > 0 else 0.0,
        (c.impacts - expected) / math.sqrt(expected) if expected > 0 else 0.0,
        s_min, r_min, r_max, (c.impacts, c.bonds, c.fractures), plant.rounds,
    )
