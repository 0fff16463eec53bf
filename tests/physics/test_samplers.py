"""The tabulated samplers of eqns (5) and (9) against the laws, computed here independently.

Eqn (9)'s CDFs are closed forms; eqn (5)'s weighted law of U_in (the larger of two Gamma(3/2)
draws, weighted by (max - min) / max, docs/model.md Sec. 3.2) is integrated here by nested
quadrature from that definition, not from the module's density.
"""

import math

import numpy as np
import pytest
from scipy import integrate, stats

from bmctl.physics import samplers as tab
from bmctl.physics.constants import MEAN_LOSS_RATIO
from bmctl.physics.impacts import sample_impact_energies

_C15 = 2 / math.sqrt(math.pi)  # 1 / Gamma(3/2)


def G15(h: float) -> float:
    """Gamma(3/2) density h^(1/2) e^(-h) / Gamma(3/2) (a closed form: scipy.stats' frozen pdf costs ~100 times
    as much per scalar call, which the nested quadratures below make millions of)."""
    return _C15 * math.sqrt(h) * math.exp(-h) if h > 0 else 0.0


def _weighted_density(h: float) -> float:
    """Density of U_in / theta: 2 g(h) int_0^h g(l) (1 - l / h) dl / E[(max - min) / max].  (5)"""
    return 2 * G15(h) * integrate.quad(lambda lo: (1 - lo / h) * G15(lo), 0, h)[0] / MEAN_LOSS_RATIO


def _weighted_cdf(y: float) -> float:
    return integrate.quad(_weighted_density, 0, y, limit=200)[0]


def _weighted_sf(y: float) -> float:
    return integrate.quad(_weighted_density, y, np.inf, limit=200)[0]


def _beta_a2_cdf(x, a):
    return x**a * ((a + 1) - a * x)  # (9): int of (a)(a+1) t^(a-1) (1 - t)


def test_energy_density_is_the_weighted_law_of_eq5():
    h = np.array([0.0, 1e-3, 0.3, 1.0, 2.5, 7.0, 30.0])
    np.testing.assert_allclose([G15(v) for v in h], stats.gamma(1.5).pdf(h), rtol=1e-13, atol=1e-300)
    y = np.array([0.05, 0.5, 1.0, 2.0, 4.0, 9.0, 20.0])
    np.testing.assert_allclose(tab.energy_density(y), [_weighted_density(v) for v in y], rtol=1e-7)
    assert integrate.quad(tab.energy_density, 0, np.inf, limit=200)[0] == pytest.approx(1.0, abs=1e-8)


def test_energy_quantiles_invert_the_cdf():
    # the draws' own uniforms from a twin generator: F(draw / theta) must give them back
    theta = 0.02
    u = np.random.default_rng(8).random(4000)
    y = tab.tabulated_energies(np.random.default_rng(8), theta, 4000) / theta
    picks = np.concatenate([np.argsort(u)[[0, 1, 40, 400, 2000, 3600, 3900]], np.flatnonzero(u > 0.99)[:3]])
    for k in picks:
        if u[k] < 0.9:
            assert abs(_weighted_cdf(y[k]) - u[k]) < 1e-5, (u[k], y[k])
        else:  # the tail: relative accuracy of 1 - F
            assert abs(_weighted_sf(y[k]) / (1 - u[k]) - 1) < 1e-4, (u[k], y[k])


@pytest.mark.parametrize("a", [1.5, 2.8, 3.1, 6.0])
def test_beta_quantiles_invert_the_closed_form_cdf(a):
    u = np.random.default_rng(9).random(200_000)
    x = tab.tabulated_beta_a2(np.random.default_rng(9), a, u.size)
    assert np.max(np.abs(_beta_a2_cdf(x, a) - u)) < 1e-5  # largest next to the ends of the range
    assert x.min() >= 0.0 and x.max() <= 1.0


@pytest.mark.parametrize("alpha,beta", [(2.1, 1.8), (1.5, 3.0)])
def test_zeta_xi_ks_and_second_moments(alpha, beta):
    rng = np.random.default_rng(10)
    z = tab.tabulated_zeta(rng, alpha, 400_000)
    x = tab.tabulated_xi(rng, beta, 400_000)
    assert stats.kstest(1 - z, lambda v: _beta_a2_cdf(v, alpha + 1)).pvalue > 0.001  # zeta ~ Beta(2, alpha+1)
    assert stats.kstest(x, lambda v: _beta_a2_cdf(v, beta + 1)).pvalue > 0.001  # xi ~ Beta(beta+1, 2)
    ez2 = 6 / ((alpha + 3) * (alpha + 4))  # E[zeta^2] of (9)
    ex2 = (beta + 1) * (beta + 2) / ((beta + 3) * (beta + 4))
    assert abs(np.mean(z**2) - ez2) < 4 * np.std(z**2) / math.sqrt(z.size)
    assert abs(np.mean(x**2) - ex2) < 4 * np.std(x**2) / math.sqrt(x.size)


@pytest.mark.slow
def test_energy_sampler_ks_against_eq5_and_the_exact_sampler():
    rng = np.random.default_rng(11)
    y = tab.tabulated_energies(rng, 1.0, 200_000)
    grid = np.concatenate([[0.0], np.geomspace(0.01, 30.0, 160)])
    F = np.array([_weighted_cdf(v) for v in grid])
    cdf = lambda v: np.interp(v, grid, F)  # piecewise-linear: within 1e-4 of the law on this grid
    assert stats.kstest(y, cdf).statistic < 1.36 / math.sqrt(y.size) + 2e-4
    exact, _ = sample_impact_energies(rng, 1.0, 200_000)
    assert stats.ks_2samp(y, exact).pvalue > 0.001
    mean = integrate.quad(lambda v: v * _weighted_density(v), 0, np.inf, limit=200)[0]
    assert abs(y.mean() - mean) < 4 * y.std() / math.sqrt(y.size)


def test_same_seed_same_draws_and_one_uniform_each():
    a, b = np.random.default_rng(12), np.random.default_rng(12)
    np.testing.assert_array_equal(tab.tabulated_energies(a, 1.0, 1000), tab.tabulated_energies(b, 1.0, 1000))
    tab.tabulated_xi(a, 1.8, 500)
    b.random(500)
    assert a.bit_generator.state == b.bit_generator.state
