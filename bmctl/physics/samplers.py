"""Tabulated inverse-CDF samplers of the impact laws (5) and (9): one uniform draw per variate.

The exact samplers of :mod:`bmctl.physics.impacts` draw each U_in from about 4.4 Gamma(3/2)
variates (a pair per try, weighted by rejection) and each zeta, xi from two Gamma variates;
in the plant those draws took half the time of an impact. These samplers invert the same
laws' CDFs from tables instead:

* U_in / theta under the weighted law of (5) (docs/model.md, Sec. 3.2): the larger of two iid
  Gamma(3/2, 1) draws, weighted by (max - min) / max. Its density is
  ``2 g(y) [P(3/2, y) - 3/2 P(5/2, y) / y] / K`` (g the Gamma(3/2) density, P the regularised
  lower incomplete gamma function, K = ``MEAN_LOSS_RATIO``); it does not depend on the card.
* Beta(a, 2), CDF ``x^a ((a + 1) - a x)``: xi = Beta(beta + 1, 2) and zeta = 1 - Beta(alpha + 1, 2) (9).

A table holds the quantile function on a uniform grid of N cells; a draw interpolates it
linearly. Where the quantile function is not smooth, at the ends of the range, the end
cells use its leading power law instead (U_in ~ u^(1/3), x ~ u^(1/a) at 0; 1 - x ~ (1 - u)^(1/2)
at 1), and the unbounded upper tail of U_in is tabulated against t = -ln(1 - u). A draw's
CDF value is within 1e-5 of its uniform (largest in the cells next to the ends, below 1e-8 in
the interior; a Kolmogorov-Smirnov test would need about 10^10 draws to see it):
``tests/physics/test_samplers.py`` checks the tables against the CDFs by quadrature, and the
samples by Kolmogorov-Smirnov tests against eqns (5) and (9). Every draw takes one ``Generator.random()`` value, so a seed gives the same stream
to the plant's numpy and compiled engines.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from . import libm
from .constants import MEAN_LOSS_RATIO

N_CELLS = 8192  # cells of every main table
ENERGY_MAIN_U = 1.0 - 1.0 / 16.0  # the energy's main table covers u < this; the tail table the rest
ENERGY_TAIL_T = (math.log(16.0), 38.0)  # t = -ln(1 - u) range of the tail table (u < 1 - 2^-53 < 1 - e^-38)
N_TAIL_CELLS = 2048


def _gammainc_half(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P(3/2, y) and P(5/2, y), regularised lower incomplete gamma functions, in closed form."""
    erf = np.frompyfunc(math.erf, 1, 1)
    root = np.sqrt(y)
    e = np.exp(-y)
    p15 = np.asarray(erf(root), dtype=float) - 2.0 * root * e / math.sqrt(math.pi)
    p25 = p15 - y * root * e / (0.75 * math.sqrt(math.pi))
    return p15, p25


def energy_density(y: np.ndarray) -> np.ndarray:
    """Density of U_in / theta under the weighted law of (5): 2 g(y) [P(3/2, y) - 3/2 P(5/2, y) / y] / K.

    Parameters
    ----------
    y : ndarray
        U_in / theta (> 0).
    """
    y = np.asarray(y, dtype=float)
    p15, p25 = _gammainc_half(y)
    g = 2.0 / math.sqrt(math.pi) * np.sqrt(y) * np.exp(-y)  # Gamma(3/2, 1) density, (5)
    return 2.0 * g * (p15 - 1.5 * p25 / y) / MEAN_LOSS_RATIO


def _running_integral(f: np.ndarray, dx: float) -> np.ndarray:
    """Running integral of samples f on a uniform grid of an even number of cells, from the first node.

    Simpson's rule at the even nodes; the quadratic through three nodes at the odd ones.
    """
    out = np.zeros_like(f)
    out[2::2] = np.cumsum(dx / 3.0 * (f[:-2:2] + 4.0 * f[1:-1:2] + f[2::2]))
    out[1::2] = out[:-1:2] + dx / 12.0 * (5.0 * f[:-2:2] + 8.0 * f[1:-1:2] - f[2::2])
    return out


@lru_cache(maxsize=1)
def energy_tables() -> tuple[np.ndarray, np.ndarray]:
    """Quantiles of U_in / theta under the weighted law of (5): the main table and the tail table.

    The main table holds Q(u) at u = k U / N (k = 0..N, U = ``ENERGY_MAIN_U``, N = ``N_CELLS``);
    the tail table holds Q(1 - exp(-t)) at t = t0 + k (t1 - t0) / N_tail (``ENERGY_TAIL_T``).
    Built once per process (about 0.1 s) from the density by quadrature in w = sqrt(y).
    """
    w = np.linspace(0.0, 7.0, 400_001)  # y = w^2 up to 49: 1 - F(49) < 1e-20
    dw = w[1] - w[0]
    y = w**2
    f = np.zeros_like(w)
    f[1:] = energy_density(y[1:]) * 2.0 * w[1:]  # density in w
    F = _running_integral(f, dw)
    S = _running_integral(f[::-1], dw)[::-1]  # survival 1 - F, summed from the top (exact in the far tail)
    total = F[-1]
    F, S = F / total, S / total
    # main table: invert F on the u grid (F increases strictly on (0, 49])
    u = np.linspace(0.0, ENERGY_MAIN_U, N_CELLS + 1)
    main = np.interp(u, F, y)
    # tail table: invert ln S against t (ln S is smooth and close to linear in y there)
    t0, t1 = ENERGY_TAIL_T
    t = np.linspace(t0, t1, N_TAIL_CELLS + 1)
    keep = S > 0
    log_s = np.log(S[keep][::-1])
    tail = np.interp(-t[::-1], log_s, y[keep][::-1])[::-1]
    return main, tail


@lru_cache(maxsize=32)
def beta_a2_table(a: float) -> np.ndarray:
    """Quantiles of Beta(a, 2), a > 0, at u = k / N (k = 0..N): the CDF x^a ((a + 1) - a x) inverted.  (9)

    Parameters
    ----------
    a : float
        First shape parameter (alpha + 1 for zeta, beta + 1 for xi).
    """
    u = np.linspace(0.0, 1.0, N_CELLS + 1)
    lo, hi = np.zeros_like(u), np.ones_like(u)
    for _ in range(64):  # bisection: the CDF increases strictly on [0, 1]
        mid = 0.5 * (lo + hi)
        below = mid**a * ((a + 1.0) - a * mid) < u
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    q = 0.5 * (lo + hi)
    q[0], q[-1] = 0.0, 1.0
    return q


def tabulated_energies(rng: np.random.Generator, theta: float, n: int) -> np.ndarray:
    """U_in of ``n`` impacts under the weighted law of (5), one uniform draw each.

    Same law as ``sample_impact_energies(rng, theta, n)[0]`` (:mod:`bmctl.physics.impacts`).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    theta : float
        Gamma scale (J).
    n : int
        Number of impacts.
    """
    main, tail = energy_tables()
    u = rng.random(n)
    z = u * (N_CELLS / ENERGY_MAIN_U)
    k = np.minimum(z.astype(np.int64), N_CELLS - 1)
    y = main[k] + (z - k) * (main[k + 1] - main[k])
    first = k == 0
    if first.any():  # Q ~ u^(1/3) at 0
        y[first] = main[1] * libm.cbrt(z[first])  # the C library's, as the compiled engine
    up = u >= ENERGY_MAIN_U
    if up.any():
        t0, t1 = ENERGY_TAIL_T
        zt = (-libm.log1p(-u[up]) - t0) * (N_TAIL_CELLS / (t1 - t0))
        kt = np.minimum(zt.astype(np.int64), N_TAIL_CELLS - 1)
        y[up] = tail[kt] + (zt - kt) * (tail[kt + 1] - tail[kt])
    return y * theta


def tabulated_beta_a2(rng: np.random.Generator, a: float, n: int) -> np.ndarray:
    """``n`` draws of Beta(a, 2), one uniform draw each (first cell x ~ u^(1/a), last 1 - x ~ (1 - u)^(1/2)).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    a : float
        First shape parameter.
    n : int
        Number of draws.
    """
    q = beta_a2_table(float(a))
    z = rng.random(n) * N_CELLS
    k = z.astype(np.int64)
    x = q[k] + (z - k) * (q[k + 1] - q[k])
    first = k == 0
    if first.any():
        x[first] = q[1] * libm.power(z[first], 1.0 / a)
    last = k == N_CELLS - 1
    if last.any():
        x[last] = 1.0 - (1.0 - q[N_CELLS - 1]) * np.sqrt(N_CELLS - z[last])
    return x


def tabulated_zeta(rng: np.random.Generator, alpha: float, n: int) -> np.ndarray:
    """Tribological factor zeta ~ Beta(2, alpha + 1) = 1 - Beta(alpha + 1, 2).  (9)

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    alpha : float
        Friction exponent of (9).
    n : int
        Number of draws.
    """
    return 1.0 - tabulated_beta_a2(rng, alpha + 1.0, n)


def tabulated_xi(rng: np.random.Generator, beta: float, n: int) -> np.ndarray:
    """Plasticity factor xi ~ Beta(beta + 1, 2).  (9)

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    beta : float
        Plasticity exponent of (9).
    n : int
        Number of draws.
    """
    return tabulated_beta_a2(rng, beta + 1.0, n)
