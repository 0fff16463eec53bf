"""Unit tests of the paper's equations at known values, and KS tests of the samplers."""

import numpy as np
import pytest
from scipy import integrate, stats

from bmctl.physics import samplers as tab
from bmctl.plant import events as ev
from bmctl.plant.kinematics import MEAN_ABS_DIFF_GAMMA15, MEAN_LOSS_RATIO


def test_eq1_size_of_circle_and_ellipse():
    d = 40e-6
    assert ev.size_from_area(np.pi * d**2 / 4) == pytest.approx(d)
    s, r = ev.ellipse_size_aspect(2.0, 1.0)
    assert s == pytest.approx(2 * np.sqrt(2))  # s = 2 sqrt(ab)
    assert r == pytest.approx(1 - 2 * np.sqrt(2) / 3)  # r = 1 - 2 sqrt(ab)/(a+b)


def test_eq3_aspect_ratio_of_circle_is_zero_and_inverse():
    s = 30e-6
    assert ev.aspect_from_perimeter(s, np.pi * s) == pytest.approx(0.0)
    r = 0.3
    assert ev.aspect_from_perimeter(s, ev.perimeter_from_aspect(s, r)) == pytest.approx(r)
    # ellipse with L = pi (a + b): (3) agrees with the closed form of Sec. 3.1
    a, b = 3.0, 1.0
    s_e, r_e = ev.ellipse_size_aspect(a, b)
    assert ev.aspect_from_perimeter(s_e, np.pi * (a + b)) == pytest.approx(r_e)


def test_eq14_critical_angle():
    assert ev.critical_angle(0.0) == pytest.approx(np.pi / 4)
    r = np.linspace(0.01, 0.95, 50)
    assert np.all(ev.critical_angle(r) > np.pi / 4)
    # psi_c = atan(a/b) for the ellipse with that r
    a, b = 2.0, 1.0
    _, r_e = ev.ellipse_size_aspect(a, b)
    assert ev.critical_angle(r_e) == pytest.approx(np.arctan(a / b))


def test_eq13_aspect_change_zero_for_circle_and_sign_follows_strain():
    assert ev.aspect_change(0.0, 0.1) == pytest.approx(0.0)
    assert ev.aspect_change(0.3, 0.1) > 0 > ev.aspect_change(0.3, -0.1)
    # sin(w) cos(w) eps with w = asin(1 - r)
    w = np.arcsin(1 - 0.3)
    assert ev.aspect_change(0.3, 0.1) == pytest.approx(0.5 * np.sin(2 * w) * 0.1)


def test_eq11_strain_sign_rule():
    r = np.full(4, 0.2)
    psi_c = ev.critical_angle(0.2)
    psi = np.array([0.0, psi_c * 0.99, psi_c * 1.01, -np.pi / 2 * 0.999])
    eps = ev.plastic_strain(np.full(4, 1e-6), np.full(4, 40e-6), 80e6, 1.0, np.cos(2 * psi), r, 10.0)
    assert np.all(eps[:2] > 0) and np.all(eps[2:] < 0)
    # magnitude (3/2) dU_p / (A s sigma)
    A = np.pi / 4 * (40e-6) ** 2
    assert abs(eps[0]) == pytest.approx(1.5e-6 / (A * 40e-6 * 80e6))


def test_eq14_strain_sign_from_cos2psi_is_the_critical_angle_rule():
    rng = np.random.default_rng(4)
    psi = rng.uniform(-np.pi / 2, np.pi / 2, 200_000)
    r = rng.uniform(0.0, ev.R_MAX, psi.size)
    by_angle = np.where(np.abs(psi) < ev.critical_angle(r), 1.0, -1.0)
    by_cos = ev.strain_sign(np.cos(2 * psi), r)
    # equal except within rounding of the boundary |psi| = psi_c
    near = np.abs(np.abs(psi) - ev.critical_angle(r)) < 1e-9
    assert np.array_equal(by_angle[~near], by_cos[~near]) and near.sum() < 5


def test_eq7_eq8_heats_from_cos2psi():
    rng = np.random.default_rng(5)
    e, psi, z, x = rng.random(100), rng.uniform(-np.pi / 2, np.pi / 2, 100), rng.random(100), rng.random(100)
    dUf, dUp = ev.impact_heats(e, np.cos(2 * psi), z, x)
    np.testing.assert_allclose(dUf, ev.friction_heat(e, psi, z), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(dUp, ev.plastic_heat(e, psi, x), rtol=1e-12, atol=1e-15)


def test_eq18_and_eq20_conserve_area():
    rng = np.random.default_rng(0)
    si, sj = rng.uniform(5e-6, 100e-6, (2, 1000))
    ri, rj = rng.uniform(0, 0.6, (2, 1000))
    d = ev.hertz_contact_length(si, sj, 0.02, 120e9)
    s, r = ev.bonded(si, ri, sj, rj, d)
    np.testing.assert_allclose(s**2, si**2 + sj**2, rtol=1e-14)
    assert np.all((r >= 0) & (r < 1))
    x = rng.random(1000)
    s1, r1, s2, r2 = ev.fractured(si, ri, x, ev.crack_length(si, x))
    np.testing.assert_allclose(s1**2 + s2**2, si**2, rtol=1e-14)
    assert np.all((r1 >= 0) & (r1 < 1) & (r2 >= 0) & (r2 < 1))


def test_eq20_half_split_of_disc_gives_half_discs():
    s = 1.0
    s1, r1, s2, r2 = ev.fractured(np.array([s]), np.array([0.0]), np.array([0.5]), ev.crack_length(s, 0.5))
    # half-disc of radius R: area pi R^2 / 2, perimeter (pi + 2) R
    R = 0.5
    s_half = 2 * np.sqrt(np.pi * R**2 / 2 / np.pi)
    r_half = 1 - np.pi * s_half / ((np.pi + 2) * R)
    assert s1[0] == pytest.approx(s_half) and r1[0] == pytest.approx(r_half) and r2[0] == pytest.approx(r_half)


def test_eq15_bond_probability_and_eq16_contact_length():
    p = ev.bond_probability(40e-6, 0.0, 40e-6, 0.0, 1.82e-4 * 1e12)
    assert p == pytest.approx(1.82e-4 * 40 * 40)  # gamma per um^2 times s_i s_j in um^2
    d = ev.hertz_contact_length(40e-6, 40e-6, 1e-6, 120e9)
    expect = 0.75 * 20e-6 * np.sqrt(3 * np.pi * 1e-6 / (120e9 * 2 * (40e-6) ** 3))
    assert d == pytest.approx(expect)


def test_eq17_threshold_probability():
    assert ev.threshold_probability(6.4, 6.4, 8.0) == pytest.approx(0.5)
    assert ev.threshold_probability(64.0, 6.4, 8.0) > 0.999
    assert ev.threshold_probability(0.64, 6.4, 8.0) < 0.01


def test_eq5_energy_sampler_ks_against_gamma():
    rng = np.random.default_rng(1)
    theta = 0.015
    u_in, u_out = ev.sample_impact_energies(rng, theta, 4000, weighted=False)
    F = stats.gamma(1.5, scale=theta).cdf
    # U_in is the larger of two iid draws from (5): cdf F^2; U_out the smaller: 1 - (1 - F)^2
    assert stats.kstest(u_in, lambda x: F(x) ** 2).pvalue > 0.01
    assert stats.kstest(u_out, lambda x: 1 - (1 - F(x)) ** 2).pvalue > 0.01
    assert np.all(u_in >= u_out)
    # the pdf printed as (5), with m v^2 = 3 theta, integrates to 1 (Gamma(3/2, m v^2))
    mv2 = 3 * theta
    pdf5 = lambda U: 2 / (np.sqrt(np.pi) * mv2) * np.sqrt(U / mv2) * np.exp(-U / mv2)
    assert integrate.quad(pdf5, 0, np.inf)[0] == pytest.approx(1.0, rel=1e-6)


@pytest.mark.slow
def test_eq5_weighted_sampler_matches_loop_weighting():
    rng = np.random.default_rng(2)
    u_in, u_out = ev.sample_impact_energies(rng, 1.0, 20000, weighted=True)
    rho = 1 - u_out / u_in
    # weighting by rho: E_w[rho] = E[rho^2] / E[rho]; E[rho^2] by quadrature
    pdf = stats.gamma(1.5).pdf
    inner = lambda hi: integrate.quad(lambda lo: (1 - lo / hi) ** 2 * pdf(lo), 0, hi)[0]
    e_rho2 = integrate.quad(lambda hi: 2 * pdf(hi) * inner(hi), 0, np.inf, limit=200)[0]
    expect = e_rho2 / MEAN_LOSS_RATIO
    se = rho.std() / np.sqrt(rho.size)
    assert abs(rho.mean() - expect) < 4 * se
    assert MEAN_ABS_DIFF_GAMMA15 == pytest.approx(4 / np.pi, rel=1e-6)


ZETA_XI = {"exact": (ev.sample_zeta, ev.sample_xi), "tabulated": (tab.tabulated_zeta, tab.tabulated_xi)}


@pytest.mark.parametrize("sampler", ZETA_XI)
@pytest.mark.parametrize("alpha,beta", [(2.1, 1.8), (2.17, 1.72), (2.05, 1.86)])
def test_eq9_zeta_xi_samplers_ks(alpha, beta, sampler):
    rng = np.random.default_rng(3)
    sample_zeta, sample_xi = ZETA_XI[sampler]
    z = sample_zeta(rng, alpha, 3000)
    x = sample_xi(rng, beta, 3000)
    pz = lambda t: (alpha + 1) * (alpha + 2) * t * (1 - t) ** alpha  # (9) as printed
    px = lambda t: (beta + 1) * (beta + 2) * t**beta * (1 - t)
    Fz = lambda v: np.array([integrate.quad(pz, 0, vi)[0] for vi in np.atleast_1d(v)])
    Fx = lambda v: np.array([integrate.quad(px, 0, vi)[0] for vi in np.atleast_1d(v)])
    assert stats.kstest(z, Fz).pvalue > 0.01
    assert stats.kstest(x, Fx).pvalue > 0.01


def test_dissipated_heat_never_exceeds_incident_energy():
    rng = np.random.default_rng(4)
    n = 10000
    e = rng.gamma(1.5, 1e-4, n)
    psi = rng.uniform(-np.pi / 2, np.pi / 2, n)
    dUd = ev.friction_heat(e, psi, ev.sample_zeta(rng, 2.1, n)) + ev.plastic_heat(e, psi, ev.sample_xi(rng, 1.8, n))
    assert np.all(dUd >= 0) and np.all(dUd <= e)
    # the mean share used by the hit rate matches the samplers
    share = (dUd / e).mean()
    assert share == pytest.approx(ev.mean_dissipated_share(2.1, 1.8), abs=4 * (dUd / e).std() / np.sqrt(n))
