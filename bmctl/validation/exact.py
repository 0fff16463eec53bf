"""Exact solutions of the analytic verification cases (area coordinate x = s^2).

Verification of the plant's population Monte Carlo engine (docs/verification.md).

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
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import integrate

from ..plant import events as ev

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
