"""The analytic verification cases and how one is run and evaluated against its exact solution.

See :mod:`bmctl.validation` and docs/verification.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from ..config import ModelCard
from ..plant.kernels import PopulationKernels, constant_agglomeration, linear_breakage, paper_bonding
from ..plant.plant import Plant, default_card
from .exact import BIAS_ALPHA, Exact, GAMMA_15, N0, SLOPE_RANGE, TIME_SCALE_S, X0, discrete_state, kernel15_matrix, smoluchowski_constant, smoluchowski_discrete, ziff_mcgrady_exponential, ziff_mcgrady_monodisperse

# --- cases ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Case:
    """An analytic verification case: initial sample, kernels and the exact solution.

    Times are in units of ``TIME_SCALE_S``; ``exact(tau)`` is the solution at those times.
    """

    name: str
    title: str
    times: tuple[float, ...]
    initial: Callable[[np.random.Generator, int], np.ndarray]
    kernels: Callable[[np.ndarray], PopulationKernels]
    exact: Callable[[float], Exact]
    x_mean0: float = X0


def _exponential_start(rng: np.random.Generator, M: int) -> np.ndarray:
    return rng.exponential(X0, size=M)


def _monodisperse_start(rng: np.random.Generator, M: int) -> np.ndarray:
    return np.full(M, X0)


def _kernel15_exact() -> Callable[[float], Exact]:
    taus = (2.0, 4.0, 7.0)
    cache: dict[float, Exact] = {}

    def exact(tau: float) -> Exact:
        if not cache:
            c, lost = smoluchowski_discrete(kernel15_matrix(600), taus)
            if lost > 1e-9:
                raise RuntimeError(f"discrete Smoluchowski reference truncated: {lost:.2e} of the mass lost")
            cache.update({t: discrete_state(ci) for t, ci in zip(taus, c)})
        return cache[tau]

    return exact


def agglomeration_constant(headroom: float = 4.0) -> Case:
    """Constant kernel, exponential start; per processed pair p = K N / rho with rho = headroom K N0.

    The bond probability follows the represented number N, which the batch reads at its
    start: a larger ``headroom`` (smaller batches in time) makes that lag smaller.
    """
    K = 1.0 / (N0 * TIME_SCALE_S)
    return Case(
        "agglomeration-constant", "Smoluchowski, constant kernel, exponential start",
        (1.0, 3.0, 9.0), _exponential_start,
        lambda x: constant_agglomeration(K, N0, headroom),
        smoluchowski_constant,
    )


def breakage_monodisperse() -> Case:
    """Linear selection rate S(x) = k x, uniform binary daughters, all particles at x0 (p = 1 at x0)."""
    k = 1.0 / (X0 * TIME_SCALE_S)
    return Case(
        "breakage-linear-mono", "Ziff-McGrady, S = k x, uniform daughters, monodisperse start",
        (0.5, 1.5, 4.0), _monodisperse_start,
        lambda x: linear_breakage(k, X0),
        ziff_mcgrady_monodisperse,
    )


def breakage_exponential() -> Case:
    """Linear selection rate, uniform daughters, exponential start (rho = k max x)."""
    k = 1.0 / (X0 * TIME_SCALE_S)
    return Case(
        "breakage-linear-exp", "Ziff-McGrady, S = k x, uniform daughters, exponential start",
        (0.5, 2.0, 8.0), _exponential_start,
        lambda x: linear_breakage(k, float(x.max())),
        ziff_mcgrady_exponential,
    )


def agglomeration_kernel15() -> Case:
    """Bonding by eqn (15) alone (r = 0, p_u = 1), monodisperse start, against the discrete Smoluchowski equation."""
    return Case(
        "agglomeration-kernel15", "eqn (15) bonding, monodisperse start, vs discrete Smoluchowski ODE",
        (2.0, 4.0, 7.0), _monodisperse_start,
        lambda x: paper_bonding(GAMMA_15, 1.0 / TIME_SCALE_S),
        _kernel15_exact(),
    )


CASES: dict[str, Callable[[], Case]] = {
    "agglomeration-constant": agglomeration_constant,
    "breakage-linear-mono": breakage_monodisperse,
    "breakage-linear-exp": breakage_exponential,
    "agglomeration-kernel15": agglomeration_kernel15,
}


# --- running a case ------------------------------------------------------------------------------

def population_plant(card: ModelCard, rng: np.random.Generator, x: np.ndarray, X: float,
                     kernels: PopulationKernels) -> Plant:
    """A plant whose M particles have areas ``x`` (r = 0) and represent total area ``X``, running ``kernels``.

    Parameters
    ----------
    card : ModelCard
        Supplies the simulation settings (batch fraction, step).
    rng : numpy.random.Generator
        The plant's generator.
    x : ndarray
        Initial x = s^2 (m^2) of the M particles.
    X : float
        Represented total area (m^2).
    kernels : PopulationKernels
        The verification kernels.
    """
    plant = Plant(card, rng, particles=x.size, kernels=kernels)
    plant.s = np.sqrt(x)
    plant.r = np.zeros(x.size)
    plant.total_area = float(X)
    return plant


def ks_distance(x: np.ndarray, ex: Exact) -> float:
    """Kolmogorov distance sup |F_M(x) - F(x)| of a sample ``x`` (already snapped) from the exact F.

    Continuous F (atoms allowed): right and left limits at the sample values; lattice F:
    every lattice point.

    Parameters
    ----------
    x : ndarray
        The sample.
    ex : Exact
        The exact distribution.
    """
    xs = np.sort(x)
    M = xs.size
    if ex.support is not None:
        grid = ex.support
        return float(np.max(np.abs(np.searchsorted(xs, grid, side="right") / M - ex.cdf(grid))))
    hi = np.searchsorted(xs, xs, side="right") / M  # F_M(x)
    lo = np.searchsorted(xs, xs, side="left") / M  # F_M(x-)
    return float(max(np.max(np.abs(hi - ex.cdf(xs))), np.max(np.abs(lo - ex.cdf(xs, left=True)))))


QUANTILES = np.linspace(0.1, 0.9, 9)


def cdf_grid(ex: Exact) -> np.ndarray:
    """Points where the exact CDF is compared: its deciles (support points for lattices)."""
    return ex.ppf(QUANTILES)


@dataclass
class Run:
    """Errors of one run (one seed, one M) at each of a case's times."""

    err_n: np.ndarray
    err_m2: np.ndarray
    ks: np.ndarray
    cdf_err: np.ndarray  # (times, quantile points): F_M - F
    samples: list[np.ndarray]  # x at each time (snapped)


def run_case(case: Case, M: int, seed: int, card: ModelCard | None = None) -> Run:
    """Run one case with M particles from one seed; errors at each of its times.

    Parameters
    ----------
    case : Case
        The case.
    M : int
        Simulated particles.
    seed : int
        Seed of the run's generator.
    card : ModelCard, optional
        Simulation settings (default: the lab card).
    """
    card = card or default_card()
    rng = np.random.default_rng(seed)
    x = case.initial(rng, M)
    X = N0 * case.x_mean0
    plant = population_plant(card, rng, x, X, case.kernels(x))
    rpm = card.process.rpm if card.process.rpm > 0 else card.mill.rpm_max / 2
    err_n, err_m2, ks, cdf_err, samples = [], [], [], [], []
    for tau in case.times:
        plant.advance(rpm, (tau * TIME_SCALE_S - plant.t_s) / 3600.0)
        ex = case.exact(tau)
        xs = ex.snap(plant.s**2)
        err_n.append(plant.represented_particles / N0 / ex.n_ratio - 1.0)
        err_m2.append(float(np.mean(xs**2)) / ex.m2 - 1.0)
        ks.append(ks_distance(xs, ex))
        g = cdf_grid(ex)
        cdf_err.append(np.searchsorted(np.sort(xs), g, side="right") / M - ex.cdf(g))
        samples.append(xs)
    return Run(np.array(err_n), np.array(err_m2), np.array(ks), np.array(cdf_err), samples)


def iid_errors(ex: Exact, M: int, rng: np.random.Generator, reps: int = 64) -> dict[str, float]:
    """Expected Monte Carlo errors of M independent draws from the exact distribution.

    ``n`` and ``m2``: standard deviations of the relative errors of N = X / mean(x) and of
    mean(x^2) (delta method); ``ks``: mean Kolmogorov distance (simulated, ``reps`` samples).

    Parameters
    ----------
    ex : Exact
        The exact distribution.
    M : int
        Sample size.
    rng : numpy.random.Generator
        Source of the simulated samples.
    reps : int, optional
        Samples for the mean Kolmogorov distance.
    """
    cv = math.sqrt(max(ex.m2 - ex.m1**2, 0.0)) / ex.m1
    cv2 = math.sqrt(max(ex.m4 - ex.m2**2, 0.0)) / ex.m2
    ks = np.mean([ks_distance(ex.snap(ex.ppf(rng.random(M))), ex) for _ in range(reps)])
    return {"n": cv / math.sqrt(M), "m2": cv2 / math.sqrt(M), "ks": float(ks)}


@dataclass
class CaseResult:
    """All runs of a case over sample sizes and seeds, with the tests' verdicts."""

    case: Case
    sizes: tuple[int, ...]
    seeds: tuple[int, ...]
    runs: dict[int, list[Run]]
    expected: dict[int, dict[str, float]]  # per M: rms over times of the i.i.d. errors
    rms: dict[int, dict[str, float]] = field(default_factory=dict)
    bias_z: dict[str, float] = field(default_factory=dict)
    bias_df: dict[str, float] = field(default_factory=dict)
    slopes: dict[str, float] = field(default_factory=dict)

    @property
    def max_z(self) -> float:
        return max(abs(z) for z in self.bias_z.values())

    @property
    def bias_p(self) -> float:
        """Bonferroni-adjusted p-value of the most extreme bias z-score (t with its Welch df)."""
        return family_p(self.bias_z, self.bias_df)

    @property
    def passed(self) -> bool:
        lo, hi = SLOPE_RANGE
        return self.bias_p > BIAS_ALPHA and all(lo <= s <= hi for s in self.slopes.values())


def family_p(z: dict[str, float], df: dict[str, float]) -> float:
    """Bonferroni-adjusted two-sided p-value of the most significant of several t statistics.

    Parameters
    ----------
    z : dict
        t statistics by name.
    df : dict
        Their degrees of freedom.
    """
    p = min(2.0 * float(stats.t.sf(abs(z[k]), df[k])) for k in z)
    return min(1.0, p * len(z))


def _pooled_z(values: dict[int, np.ndarray]) -> tuple[float, float]:
    """t statistic of the mean error pooled over sample sizes (weights ~ M), and its Welch-Satterthwaite df.

    The variance of a run's error falls as 1/M, so weights proportional to M are the
    inverse-variance weights of the seed means.
    """
    w = {M: float(M) for M in values}
    tot = sum(w.values())
    mean = sum(w[M] * v.mean() for M, v in values.items()) / tot
    parts = {M: w[M] ** 2 * v.var(ddof=1) / v.size / tot**2 for M, v in values.items()}
    var = sum(parts.values())
    if var <= 0:
        return (0.0 if mean == 0 else math.inf), 1.0
    df = var**2 / sum(parts[M] ** 2 / (values[M].size - 1) for M in values)
    return float(mean / math.sqrt(var)), float(df)


def evaluate(case: Case, sizes: Sequence[int], seeds: Sequence[int], card: ModelCard | None = None,
             progress: Callable[[str], None] | None = None) -> CaseResult:
    """Run ``case`` for every M in ``sizes`` and seed in ``seeds``; bias z-scores and M^-1/2 slopes.

    Bias: for N, E[x^2] and the CDF at the exact deciles, at each time, the seed means pooled
    over M are tested against 0 (t statistics, Welch df; the most extreme one, Bonferroni
    adjusted, must have p > ``BIAS_ALPHA``). Trend: the slope of
    log(rms error over seeds and times) against log M, for N, E[x^2] and the Kolmogorov
    distance, must lie in ``SLOPE_RANGE``.

    Parameters
    ----------
    case : Case
        The case.
    sizes : sequence of int
        Sample sizes M.
    seeds : sequence of int
        Seeds (the same for every M).
    card : ModelCard, optional
        Simulation settings (default: the lab card).
    progress : callable, optional
        Called with a line per sample size.
    """
    card = card or default_card()
    runs = {}
    expected = {}
    rng = np.random.default_rng(12345)
    for M in sizes:
        if progress:
            progress(f"{case.name}: M={M}")
        runs[M] = [run_case(case, M, seed, card) for seed in seeds]
        errs = [iid_errors(case.exact(t), M, rng) for t in case.times]
        expected[M] = {k: float(np.sqrt(np.mean([e[k] ** 2 for e in errs]))) for k in ("n", "m2", "ks")}
    res = CaseResult(case, tuple(sizes), tuple(seeds), runs, expected)
    for M, rs in runs.items():
        res.rms[M] = {
            "n": float(np.sqrt(np.mean([r.err_n**2 for r in rs]))),
            "m2": float(np.sqrt(np.mean([r.err_m2**2 for r in rs]))),
            "ks": float(np.sqrt(np.mean([r.ks**2 for r in rs]))),
        }
    for ti, tau in enumerate(case.times):
        tests = {f"n@{tau:g}": lambda r: r.err_n[ti], f"m2@{tau:g}": lambda r: r.err_m2[ti]}
        for qi, q in enumerate(QUANTILES):
            tests[f"F{q:.1f}@{tau:g}"] = lambda r, qi=qi: r.cdf_err[ti, qi]
        for key, get in tests.items():
            res.bias_z[key], res.bias_df[key] = _pooled_z(
                {M: np.array([get(r) for r in rs]) for M, rs in runs.items()})
    if len(sizes) >= 2:
        lm = np.log(np.array(sizes, dtype=float))
        for key in ("n", "m2", "ks"):
            res.slopes[key] = float(np.polyfit(lm, np.log([res.rms[M][key] for M in sizes]), 1)[0])
    return res
