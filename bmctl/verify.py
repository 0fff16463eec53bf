"""Verification of the plant's population Monte Carlo engine (docs/verification.md).

Three groups of checks, each a small pure function of a seed and a sample size:

* analytic cases (:data:`CASES`): the plant's event machinery (pair batches, constant-number
  rebalancing, weights) runs simple kernels (:mod:`bmctl.plant.kernels`) with known solutions
  in the area coordinate x = s^2: constant-kernel Smoluchowski agglomeration, Ziff-McGrady
  linear breakage (monodisperse and exponential start) and bonding by eqn (15) against the
  discrete Smoluchowski equation solved to convergence;
* the batched plant against the one-collision-at-a-time reference (:mod:`bmctl.plant.reference`)
  on the model cards (:func:`compare_reference`);
* bookkeeping in long runs (:func:`bookkeeping`): area conservation in every event, the
  represented number against the event counts, s > 0 and 0 <= r < 1.

Errors are relative errors of the represented number N and of the first two moments of x
(the first, E[x] = X / N, is N's error with the sign flipped), and the Kolmogorov distance
between the simulated and the exact distribution of x. The expected Monte Carlo error is
that of M independent draws from the exact distribution. A bias is tested across seeds
and sample sizes (t statistics of the seed means with Welch df, Bonferroni over a case's
quantities), the M^-1/2 trend by the slope of log(rms error) over log M.

References
----------
Smith, M., Matsoukas, T. (1998). Constant-number Monte Carlo simulation of population
balances. Chem. Eng. Sci. 53, 1777-1786.

Ziff, R. M., McGrady, E. D. (1985). The kinetics of cluster fragmentation and
depolymerisation. J. Phys. A 18, 3027-3037.  (linear breakage, uniform daughters)

Aldous, D. J. (1999). Deterministic and stochastic models for coalescence (aggregation
and coagulation). Bernoulli 5, 3-48.  (constant kernel, exponential self-similar solution)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import integrate, stats

from .config import ModelCard
from .plant import events as ev
from .plant.kernels import (PopulationKernels, constant_agglomeration, dissipation_coefficients,
                            linear_breakage, paper_bonding)
from .plant.plant import Plant, default_card

X0 = (40e-6) ** 2  # m^2: area coordinate of a 40 um particle, the unit of x
N0 = 1e7  # represented number of particles at t = 0 (any value: the kernels scale with it)
TIME_SCALE_S = 100.0  # seconds per unit of each case's dimensionless time
GAMMA_15 = 1.82e-4 * 1e12  # 1/m^2: eqn (15) factor, the paper's printed value (Sec. 4.1), um^-2 -> m^-2
Z_BIAS = 4.0  # |z| above this flags a bias where the standard error is well known (about 6e-5 per test)
BIAS_ALPHA = 0.01  # family-wise level of the seed-mean tests of one case or card (Bonferroni, t with Welch df)
SLOPE_RANGE = (-0.8, -0.2)  # accepted slope of log(rms error) against log M (ideal -0.5)


# --- exact solutions ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Exact:
    """The exact population at one time, per particle, in the area coordinate x (m^2).

    Attributes
    ----------
    n_ratio : float
        N(t) / N(0).
    m1, m2, m4 : float
        E[x], E[x^2], E[x^4] (E[x^4] gives the sampling error of E[x^2]).
    cdf : callable
        F(x) = P(X <= x); ``cdf(x, left=True)`` is P(X < x).
    ppf : callable
        Quantile function (for i.i.d. reference samples).
    support : ndarray or None
        The support of a lattice distribution k x0, k = 1..K (None: continuous).
    atoms : tuple of float
        Points carrying a share of the number (a continuous distribution's atoms).
    """

    n_ratio: float
    m1: float
    m2: float
    m4: float
    cdf: Callable[..., np.ndarray]
    ppf: Callable[[np.ndarray], np.ndarray]
    support: np.ndarray | None = None
    atoms: tuple[float, ...] = ()

    def snap(self, x: np.ndarray) -> np.ndarray:
        """Sample values moved onto the lattice or atoms they stand for (s^2 rounds in the last digit).

        Parameters
        ----------
        x : ndarray
            Sample of x (m^2).
        """
        x = np.asarray(x, dtype=float)
        if self.support is not None:
            return np.rint(x / self.support[0]) * self.support[0]
        for a in self.atoms:
            x = np.where(np.abs(x / a - 1.0) < 1e-9, a, x)
        return x


def exponential_state(n_ratio: float, mean: float) -> Exact:
    """An exponential distribution of x (self-similar solutions).

    Parameters
    ----------
    n_ratio : float
        N(t) / N(0).
    mean : float
        E[x] (m^2).
    """
    def cdf(x, left=False):
        return -np.expm1(-np.maximum(np.asarray(x, dtype=float), 0.0) / mean)

    return Exact(n_ratio, mean, 2 * mean**2, 24 * mean**4, cdf, lambda q: -mean * np.log1p(-np.asarray(q)))


def smoluchowski_constant(tau: float, x_mean0: float = X0) -> Exact:
    """Constant kernel K from an exponential start, tau = K N0 t.

    N(t) = N0 / (1 + tau/2) and n(x, t) = N^2 / X exp(-x N / X) with X the total area
    (Smoluchowski 1917; Aldous 1999, Sec. 2.2).

    Parameters
    ----------
    tau : float
        Dimensionless time K N0 t.
    x_mean0 : float, optional
        E[x] at t = 0 (m^2).
    """
    n = 1.0 / (1.0 + tau / 2.0)
    return exponential_state(n, x_mean0 / n)


def ziff_mcgrady_exponential(tau: float, x_mean0: float = X0) -> Exact:
    """Binary breakage with S(x) = k x and uniform daughters from an exponential start, tau = k E[x](0) t.

    dN/dt = k X exactly, and the exponential shape is kept: n(x, t) = N^2 / X exp(-x N / X)
    with N = N0 (1 + tau) (Ziff & McGrady 1985; substitution into the breakage equation).

    Parameters
    ----------
    tau : float
        Dimensionless time k E[x](0) t.
    x_mean0 : float, optional
        E[x] at t = 0 (m^2).
    """
    n = 1.0 + tau
    return exponential_state(n, x_mean0 / n)


def ziff_mcgrady_monodisperse(tau: float, x0: float = X0) -> Exact:
    """Binary breakage with S(x) = k x and uniform daughters from n(x, 0) = N0 delta(x - x0), tau = k x0 t.

    With u = x / x0 (Ziff & McGrady 1985, eqn 19 with a linear rate):
    n(u, t) / N0 = exp(-tau) delta(u - 1) + exp(-tau u) (2 tau + tau^2 (1 - u)), 0 < u < 1,
    so N / N0 = 1 + tau and the unbroken particles are a share exp(-tau) / (1 + tau).

    Parameters
    ----------
    tau : float
        Dimensionless time k x0 t.
    x0 : float, optional
        The initial x (m^2).
    """
    n = 1.0 + tau
    atom = math.exp(-tau)

    def g(u):
        return np.exp(-tau * u) * (2 * tau + tau**2 * (1 - u))

    def moment(m):
        return x0**m * (integrate.quad(lambda u: u**m * g(u), 0.0, 1.0, epsabs=0, epsrel=1e-12)[0] + atom) / n

    def cdf(x, left=False):
        u = np.asarray(x, dtype=float) / x0
        uc = np.clip(u, 0.0, 1.0)
        cont = ((1 + tau) - np.exp(-tau * uc) * (1 + tau - tau * uc)) / n  # integral of g from 0 to u, over N
        past_atom = (u > 1.0) if left else (u >= 1.0)
        return np.where(past_atom, 1.0, cont)

    grid = np.linspace(0.0, 1.0, 20001)
    cgrid = cdf(grid * x0, left=True)

    def ppf(q):
        q = np.asarray(q, dtype=float)
        return np.where(q >= cgrid[-1], x0, np.interp(q, cgrid, grid) * x0)

    return Exact(n, moment(1), moment(2), moment(4), cdf, ppf, atoms=(x0,))


def discrete_state(c: np.ndarray, x0: float = X0) -> Exact:
    """An Exact from number fractions c_k of k-mers (k = 1..K) with N / N0 = sum(c).

    Parameters
    ----------
    c : ndarray
        c_k = n_k / N0.
    x0 : float, optional
        x of a monomer (m^2).
    """
    n = float(c.sum())
    f = c / n
    k = np.arange(1, c.size + 1, dtype=float)
    cum = np.cumsum(f)

    def cdf(x, left=False):
        kk = np.asarray(x, dtype=float) / x0
        idx = (np.ceil(kk - 1e-6) - 1) if left else np.floor(kk + 1e-6)  # number of k-values <= (or <) x
        idx = np.clip(idx.astype(int), 0, c.size)
        return np.concatenate([[0.0], cum])[idx]

    def ppf(q):
        return x0 * (np.searchsorted(cum, np.asarray(q) * cum[-1], side="left") + 1.0)

    return Exact(n, x0 * float(f @ k), x0**2 * float(f @ k**2), x0**4 * float(f @ k**4), cdf, ppf, support=k * x0)


def smoluchowski_discrete(p: np.ndarray, taus: Sequence[float], rtol: float = 1e-10) -> tuple[np.ndarray, float]:
    """Number fractions c_k(tau) of k-mers (k = 1..K) under bonding probability p[k-1, l-1] per processed pair.

    Pairs are processed at rate rho per particle (rho N / 2 pairs per unit time, uniform
    over pairs), tau = rho t, so the kernel is K_kl = rho p_kl / N and
    dc_k/dtau = (1/nu) [1/2 sum_{i+j=k} p_ij c_i c_j - c_k sum_j p_kj c_j], nu = sum_k c_k,
    from c_1(0) = 1. Sizes above K are dropped (the returned truncation loss is the lost mass).

    Parameters
    ----------
    p : ndarray, shape (K, K)
        Bond probability of a processed pair of a k-mer and an l-mer; 1 - p may be non-zero
        only for small k, l (a corner), as for clipped kernels.
    taus : sequence of float
        Output times (tau = rho t).
    rtol : float, optional
        Relative tolerance of the RK45 integration.

    Returns
    -------
    c : ndarray, shape (len(taus), K)
    lost : float
        Largest share of the mass beyond K at the requested times.
    """
    K = p.shape[0]
    # p = 1 - q with q non-zero only in a small corner (clipped kernels): gain and loss by convolution
    corner = int(np.max(np.nonzero((1.0 - p).any(axis=1))[0]) + 1) if (p < 1).any() else 0
    q = 1.0 - p[:corner, :corner]
    qk = np.add.outer(np.arange(corner), np.arange(corner)) + 1  # 0-based indices a, b: size a+b+2, index a+b+1

    def rhs(_t, c):
        nu = c.sum()
        gain = np.zeros(K)
        conv = np.convolve(c, c)[: K - 1]  # index m: sizes summing to m + 2
        gain[1:] = 0.5 * conv
        if corner:
            cc = c[:corner]
            qc = q * np.outer(cc, cc)
            gain -= 0.5 * np.bincount(qk.ravel(), qc.ravel(), minlength=K + corner)[:K]
        loss = c * nu
        if corner:
            loss[:corner] -= c[:corner] * (q @ c[:corner])
        return (gain - loss) / nu

    c0 = np.zeros(K)
    c0[0] = 1.0
    sol = integrate.solve_ivp(rhs, (0.0, max(taus)), c0, t_eval=list(taus), method="RK45", rtol=rtol, atol=1e-14)
    c = sol.y.T
    k = np.arange(1, K + 1)
    lost = float(np.max(1.0 - c @ k))
    return c, lost


def kernel15_matrix(K: int, x0: float = X0, gamma: float = GAMMA_15) -> np.ndarray:
    """p_b of eqn (15) for round k- and l-mers (s^2 = k x0, r = 0): min(gamma s_k s_l, 1).

    Parameters
    ----------
    K : int
        Largest size.
    x0 : float, optional
        x of a monomer (m^2).
    gamma : float, optional
        Factor of (15), 1/m^2.
    """
    s = np.sqrt(np.arange(1, K + 1) * x0)
    return ev.bond_probability(s[:, None], 0.0, s[None, :], 0.0, gamma)  # (15)


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
    from .plant.kinematics import kinematics

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
    u_p, _ = ev.sample_impact_energies(rng, kin.energy_scale, big)
    psi_p = plant.kernels.sample_psi(plant, rng, big)
    return Energetics(rate, rate_se, wald, wald_se, float(over.mean()), plant.hit_rate(kin), pl, pl_se, float(np.mean(np.cos(2 * psi_p) ** 2)),
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
    from .plant.population import moments as pop_moments

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
        The model card (its recipe, :func:`bmctl.config.card_schedule`).
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
    from .config import card_schedule
    from .plant.reference import ReferencePlant

    segments = card_schedule(card, hours)
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


def long_schedule(card: ModelCard, scale: float = 1.0) -> list[tuple[float, float]]:
    """48 h (times ``scale``): the card's rpm, a rest, rpm_max, a rest, the mid speed.

    Parameters
    ----------
    card : ModelCard
        Supplies the rpm and rpm_max.
    scale : float, optional
        Factor on every segment's length.
    """
    out = []
    for h, rpm in LONG_SCHEDULE:
        speed = card.process.rpm if rpm is None else card.mill.rpm_max if rpm == "max" else \
            0.5 * (card.process.rpm + card.mill.rpm_max) if rpm == "mid" else rpm
        out.append((h * scale, float(speed)))
    return out


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
    from .plant.kinematics import kinematics

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


# --- the whole verification: settings, table, figures ------------------------------------------------

@dataclass(frozen=True)
class Settings:
    """Sizes of the verification runs (``QUICK`` and ``FULL``)."""

    sizes: tuple[int, ...]
    seeds: int
    ref_particles: int
    ref_hours: float
    ref_seeds: int
    collisions: int
    book_particles: int
    book_scale: float


QUICK = Settings(sizes=(500, 2000, 8000), seeds=6, ref_particles=500, ref_hours=0.25, ref_seeds=12,
                 collisions=5000, book_particles=1000, book_scale=0.25)
FULL = Settings(sizes=(1000, 4000, 16000), seeds=8, ref_particles=1000, ref_hours=0.5, ref_seeds=32,
                collisions=20000, book_particles=3000, book_scale=1.0)
ERROR_FACTOR = 3.0  # an rms error above this many expected (i.i.d.) Monte Carlo errors fails


@dataclass
class Report:
    """Everything one verification produced."""

    settings: Settings
    seed: int
    analytic: list[CaseResult]
    energetics: dict[str, Energetics]
    reference: list[ReferenceComparison]
    bookkeeping: list[Bookkeeping]

    @property
    def passed(self) -> bool:
        return all(r[-1] != "FAIL" for r in rows(self))


def run_all(settings: Settings, seed: int, cards: Sequence[ModelCard],
            progress: Callable[[str], None] | None = None) -> Report:
    """Every check with ``settings``.

    Parameters
    ----------
    settings : Settings
        Sizes of the runs (:data:`QUICK`, :data:`FULL`).
    seed : int
        First seed.
    cards : sequence of ModelCard
        Cards for the loop, reference and bookkeeping checks.
    progress : callable, optional
        Called with progress lines.
    """
    seeds = tuple(range(seed, seed + settings.seeds))
    analytic = [evaluate(make(), settings.sizes, seeds, progress=progress) for make in CASES.values()]
    energ, ref, book = {}, [], []
    for card in cards:
        name = card.card.name
        if progress:
            progress(f"{name}: loop energetics")
        energ[name] = energetics(card, card.process.rpm, settings.collisions, seed)
        ref.append(compare_reference(card, settings.ref_hours, settings.ref_particles,
                                     range(seed, seed + settings.ref_seeds), progress=progress))
        if progress:
            progress(f"{name}: long-run bookkeeping")
        book.append(bookkeeping(card, settings.book_particles, seed, settings.book_scale))
    return Report(settings, seed, analytic, energ, ref, book)


HEADER = ("check", "case", "M", "quantity", "error", "expected", "result")


def _ok(flag: bool) -> str:
    return "pass" if flag else "FAIL"


def rows(report: Report) -> list[tuple]:
    """The verification table: one row per quantity (``HEADER``); ``info`` rows are not tests.

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    """
    out = []
    names = {"n": "N rel. error (rms)", "m2": "E[x^2] rel. error (rms)", "ks": "Kolmogorov distance (rms)"}
    for res in report.analytic:
        c = res.case.name
        for M in res.sizes:
            for k, label in names.items():
                err, exp = res.rms[M][k], res.expected[M][k]
                out.append(("analytic", c, M, label, f"{err:.4f}", f"{exp:.4f}", _ok(err <= ERROR_FACTOR * exp)))
        worst = max(res.bias_z, key=lambda key: abs(res.bias_z[key]))
        out.append(("analytic", c, "all", f"bias: max |t| {res.max_z:.2f} ({worst}), of {len(res.bias_z)}",
                    f"p = {res.bias_p:.3f}", f"p > {BIAS_ALPHA:g}", _ok(res.bias_p > BIAS_ALPHA)))
        lo, hi = SLOPE_RANGE
        for k, s in res.slopes.items():
            out.append(("analytic", c, "all", f"slope of log rms {k} vs log M", f"{s:+.2f}", "-0.50",
                        _ok(lo <= s <= hi)))
    for name, e in report.energetics.items():
        z = e.z()
        out.append(("loop", name, "", "hit rate / plant - 1 (overshoot removed)", f"{e.rate_wald / e.rate_plant - 1:+.4f}",
                    f"{e.rate_wald_se / e.rate_plant:.4f}", _ok(abs(z["rate"]) < Z_BIAS)))
        out.append(("loop", name, "", "plastic share cos^2(2psi) - plant", f"{e.plastic_loop - e.plastic_plant:+.4f}",
                    f"{e.plastic_loop_se:.4f}", _ok(abs(z["plastic"]) < Z_BIAS)))
        out.append(("loop", name, "", "mean U_in / plant - 1", f"{e.u_in_loop / e.u_in_plant - 1:+.4f}",
                    f"{e.u_in_loop_se / e.u_in_plant:.4f}", _ok(abs(z["u_in"]) < Z_BIAS)))
        out.append(("loop", name, "", f"overshoot, impacts per collision (of {e.steps_per_collision:.0f})",
                    f"{e.overshoot:.3f}", "(1+CV^2)/2", "info"))
    for cmp in report.reference:
        for k in REFERENCE_MOMENTS:
            a, b = cmp.plant[k], cmp.reference[k]
            se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
            out.append(("reference", cmp.card, cmp.particles, f"{k}: plant - reference (t = {cmp.z[k]:+.2f})",
                        f"{a.mean() - b.mean():+.4f}", f"{se:.4f}", "info"))
        out.append(("reference", cmp.card, cmp.particles, f"moments: max |t| of {len(cmp.z)}",
                    f"p = {cmp.moments_p:.3f}", f"p > {BIAS_ALPHA:g}", _ok(cmp.moments_p > BIAS_ALPHA)))
        for k, (d, p) in cmp.ks.items():
            out.append(("reference", cmp.card, cmp.particles, f"KS final {k} (p = {p:.3f})", f"{d:.4f}",
                        f"p > {KS_ALPHA:g}", _ok(p > KS_ALPHA)))
    for b in report.bookkeeping:
        out.append(("bookkeeping", b.card, b.particles, f"area change in a round's events ({b.hours:g} h)",
                    f"{b.area_err:.1e}", "< 1e-12", _ok(b.area_err < 1e-12)))
        out.append(("bookkeeping", b.card, b.particles, "w sum(s^2) / X - 1 at the end", f"{b.total_area_err:.1e}",
                    "< 1e-12", _ok(b.total_area_err < 1e-12)))
        out.append(("bookkeeping", b.card, b.particles, "log N vs event balance (z)", f"{b.n_z:+.2f}",
                    f"|z| < {Z_BIAS:g}", _ok(abs(b.n_z) < Z_BIAS)))
        out.append(("bookkeeping", b.card, b.particles, f"impacts {b.counts[0]} vs hit rate (z)", f"{b.impacts_z:+.2f}",
                    f"|z| < {Z_BIAS:g}", _ok(abs(b.impacts_z) < Z_BIAS)))
        out.append(("bookkeeping", b.card, b.particles, "min s (um); r range", f"{b.s_min * 1e6:.3f}; "
                    f"[{b.r_min:.3f}, {b.r_max:.3f}]", "> 0; [0, 1)", _ok(b.s_min > 0 and b.r_min >= 0 and b.r_max < 1)))
    return out


def format_table(table: Sequence[tuple]) -> str:
    """Plain-text table with aligned columns.

    Parameters
    ----------
    table : sequence of tuple
        Rows of :func:`rows`.
    """
    cells = [HEADER] + [tuple(str(c) for c in row) for row in table]
    widths = [max(len(r[k]) for r in cells) for k in range(len(HEADER))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _pdf_panel(ax, res: CaseResult) -> None:
    """Exact against simulated distributions of x / x0 at the case's times (largest M, pooled seeds)."""
    M = res.sizes[-1]
    colors = ("tab:blue", "tab:orange", "tab:green")
    for ti, tau in enumerate(res.case.times):
        ex = res.case.exact(tau)
        xs = np.concatenate([r.samples[ti] for r in res.runs[M]]) / X0
        col = colors[ti % len(colors)]
        if ex.support is not None:
            k = np.arange(1, min(int(xs.max()), 60) + 1)
            f_sim = np.bincount(np.rint(xs).astype(int), minlength=k[-1] + 1)[1:k[-1] + 1] / xs.size
            f_ex = np.diff(ex.cdf(np.concatenate([[0.0], k]) * X0))
            ax.plot(k, f_ex, "-", color=col, lw=1.2, label=f"exact, tau={tau:g}")
            ax.plot(k, f_sim, "o", color=col, ms=3, label=f"simulated, tau={tau:g}")
            ax.set_xlabel("k = x / x0")
            ax.set_ylabel("number fraction")
        else:
            hi = float(np.quantile(xs, 0.995))
            edges = np.linspace(0.0, hi, 41)
            cont = xs < 1.0 - 1e-9 if ex.atoms else np.ones(xs.size, bool)
            h = np.histogram(xs[cont], bins=edges)[0] / (xs.size * np.diff(edges))
            mid = 0.5 * (edges[1:] + edges[:-1])
            dens = np.diff(ex.cdf(edges * X0, left=True)) / np.diff(edges)
            ax.plot(mid, dens, "-", color=col, lw=1.2, label=f"exact, tau={tau:g}")
            ax.plot(mid, h, "o", color=col, ms=3, label=f"simulated, tau={tau:g}")
            if ex.atoms:
                a_ex = 1.0 - float(ex.cdf(X0, left=True))
                a_sim = float(np.mean(~cont))
                ax.annotate(f"unbroken: {a_sim:.3f} (exact {a_ex:.3f})", (0.35, 0.9 - 0.08 * ti), xycoords="axes fraction",
                            color=col, fontsize=7)
            ax.set_xlabel("x / x0 (x = s^2, x0 = (40 um)^2)")
            ax.set_ylabel("number density")
    ax.set_yscale("log")
    ax.set_title(f"{res.case.name} (M = {M}, {len(res.seeds)} seeds)", fontsize=9)
    ax.legend(fontsize=6, ncol=2)
    ax.grid(alpha=0.3)


def analytic_figure(report: Report, path) -> None:
    """Exact and simulated distributions of every analytic case (one panel per case).

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    path : path-like
        PNG file (written atomically).
    """
    from .io import pyplot, savefig

    plt = pyplot()

    n = len(report.analytic)
    fig, axes = plt.subplots(2, (n + 1) // 2, figsize=(11, 8))
    for ax, res in zip(np.ravel(axes), report.analytic):
        _pdf_panel(ax, res)
    fig.suptitle("bmctl verify: analytic population balances vs the plant's Monte Carlo engine")
    fig.tight_layout()
    savefig(fig, path, dpi=110)


def reference_figure(report: Report, path) -> None:
    """Final s and r distributions of the plant and the reference, pooled over seeds, per card.

    Parameters
    ----------
    report : Report
        What :func:`run_all` produced.
    path : path-like
        PNG file (written atomically).
    """
    from .io import pyplot, savefig

    plt = pyplot()

    n = len(report.reference)
    fig, axes = plt.subplots(2, n, figsize=(4 * n, 6.5), squeeze=False)
    for col, cmp in enumerate(report.reference):
        for row, (a, b, label) in enumerate(((cmp.plant_s, cmp.ref_s, "size s (um)"), (cmp.plant_r, cmp.ref_r, "aspect ratio r"))):
            ax = axes[row, col]
            pa, pb = np.concatenate(a), np.concatenate(b)
            hi = float(np.quantile(np.concatenate([pa, pb]), 0.995))
            edges = np.linspace(0.0, hi, 41)
            ax.hist(pa, bins=edges, density=True, histtype="step", lw=1.4, label="plant (batched)")
            ax.hist(pb, bins=edges, density=True, histtype="step", lw=1.4, ls="--", label="reference (one at a time)")
            ax.set_xlabel(label)
            ax.grid(alpha=0.3)
            if row == 1:
                ax.set_yscale("log")
            d, p = cmp.ks["s" if row == 0 else "r"]
            ax.set_title(f"{cmp.card}\nKS {d:.3f}, p = {p:.2f}", fontsize=8)
            if row == 0 and col == 0:
                ax.legend(fontsize=7)
    fig.suptitle(f"plant vs reference after {report.reference[0].hours:g} h, M = {report.reference[0].particles}, "
                 f"{len(report.reference[0].seeds)} seeds")
    fig.tight_layout()
    savefig(fig, path, dpi=110)
