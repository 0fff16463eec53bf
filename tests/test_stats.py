"""Weighted size statistics (bmctl.stats) against analytic laws, and the population.npz metadata."""

import numpy as np
import pytest
from scipy import integrate, stats

from bmctl import stats as st


def test_weighted_quantile_uniform_sample_matches_the_law():
    x = np.random.default_rng(0).uniform(0.0, 1.0, 200_000)
    q = st.weighted_quantile(x, [0.1, 0.5, 0.9])
    np.testing.assert_allclose(q, [0.1, 0.5, 0.9], atol=0.005)


def test_weighted_quantile_with_weights_x_on_uniform_is_sqrt():
    # density 2x on [0, 1] (uniform weighted by x): quantile sqrt(q)
    x = np.random.default_rng(1).uniform(0.0, 1.0, 200_000)
    q = st.weighted_quantile(x, [0.1, 0.5, 0.9], weights=x)
    np.testing.assert_allclose(q, np.sqrt([0.1, 0.5, 0.9]), atol=0.005)


def test_weighted_quantile_integer_weights_equal_repetition():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    w = np.array([1, 3, 1, 2])
    rep = np.repeat(x, w)
    for q in (0.2, 0.5, 0.8):
        # midpoint rule on repeated values: within one grid step of the repeated sample's median
        assert abs(st.weighted_quantile(x, q, w) - np.quantile(rep, q)) <= 1.0


def test_weighted_quantile_rejects_bad_input():
    with pytest.raises(ValueError):
        st.weighted_quantile(np.array([]), 0.5)
    with pytest.raises(ValueError):
        st.weighted_quantile(np.array([1.0, 2.0]), 0.5, np.zeros(2))


def test_volume_dvalues_of_a_lognormal_sample_match_hatch_choate():
    mu, sigma = np.log(40.0), 0.5
    s = np.random.default_rng(2).lognormal(mu, sigma, 400_000)
    d = st.dvalues(s, 3)
    for key, q in st.DVALUE_QUANTILES.items():
        assert d[key] == pytest.approx(np.exp(mu + 3 * sigma**2 + stats.norm.ppf(q) * sigma), rel=0.02)
    assert d["span"] == pytest.approx(np.exp(1.2816 * sigma) - np.exp(-1.2816 * sigma), rel=0.03)


def test_area_weighted_mean_and_mode_of_a_lognormal_sample():
    mu, sigma = np.log(40.0), 0.4
    s = np.random.default_rng(3).lognormal(mu, sigma, 400_000)
    assert st.weighted_mean(s, 2) == pytest.approx(np.exp(mu + 2.5 * sigma**2), rel=0.01)  # Sauter mean
    assert st.weighted_mode(s, 2, smooth_bins=4.0) == pytest.approx(np.exp(mu + sigma**2), abs=2.5)
    assert st.weighted_mode(s, 0, smooth_bins=4.0) == pytest.approx(np.exp(mu - sigma**2), abs=2.5)


@pytest.mark.parametrize("mean,std", [(40.0, 4.0), (65.0, 40.0), (30.0, 25.0)])
def test_closed_form_lognormal_dvalues_against_numerical_integration(mean, std):
    """Volume-weighted quantiles by integrating s^3 f(s) numerically, against the closed form."""
    st_ = st.lognormal_size_stats(mean, std)
    sig2 = np.log1p((std / mean) ** 2)
    law = stats.lognorm(s=np.sqrt(sig2), scale=mean / np.sqrt(1 + (std / mean) ** 2))
    assert law.mean() == pytest.approx(mean) and law.std() == pytest.approx(std)
    # s^k f(s) on a fine log grid (ln s from mu - 12 sigma to mu + 20 sigma), trapezoid cumulative integrals
    sig, mu = np.sqrt(sig2), np.log(law.median())
    s = np.exp(np.linspace(mu - 12 * sig, mu + 20 * sig, 400_001))
    f = law.pdf(s)
    cum3 = integrate.cumulative_trapezoid(s**3 * f, s, initial=0.0)
    cum2 = integrate.cumulative_trapezoid(s**2 * f, s, initial=0.0)
    for key, q in st.DVALUE_QUANTILES.items():
        assert float(st_[key]) == pytest.approx(np.interp(q, cum3 / cum3[-1], s), rel=1e-4)
    d10, d50, d90 = (float(st_[k]) for k in ("d10_um", "d50_um", "d90_um"))
    assert float(st_["span"]) == pytest.approx((d90 - d10) / d50, rel=1e-9)
    # area-weighted mean = integral s^3 f / integral s^2 f; area-weighted mode = argmax s^2 f(s)
    assert float(st_["s_mean_area_um"]) == pytest.approx(cum3[-1] / cum2[-1], rel=1e-5)
    assert float(st_["s_mode_area_um"]) == pytest.approx(s[np.argmax(s**2 * f)], rel=1e-4)


def test_closed_form_accepts_casadi_symbols():
    ca = pytest.importorskip("casadi")
    m, s = ca.SX.sym("m"), ca.SX.sym("s")
    out = st.lognormal_size_stats(m, s)
    f = ca.Function("f", [m, s], [out[k] for k in st.SIZE_STAT_NAMES])
    got = [float(v) for v in f(65.0, 40.0)]
    want = [float(v) for v in st.lognormal_size_stats(np.array(65.0), np.array(40.0)).values()]
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.slow
def test_population_npz_names_weightings_and_loads_without_pickle(tmp_path):
    from bmctl.plant import default_card
    from bmctl import io
    from bmctl.simulate import population_arrays, simulate

    res = simulate(default_card(), [(0.5, 300.0)], seed=0, particles=400)
    io.savez(tmp_path / "population.npz", **population_arrays(res))
    pop = np.load(tmp_path / "population.npz", allow_pickle=False)
    names = list(pop["variables"])
    assert {"p", "p_area", "p_volume", "s_edges_um", "r_edges", "t_h"} <= set(names)
    assert dict(zip(names, pop["units"]))["s_edges_um"] == "um"
    assert "s^3" in dict(zip(names, pop["meaning"]))["p_volume"]
    for key in ("p", "p_area", "p_volume"):
        np.testing.assert_allclose(pop[key].sum(axis=(1, 2)), 1.0, rtol=1e-4)
    # volume raster weights the number raster by s^3 at the bin centres
    c = pop["s_centers_um"]
    pv = pop["p"][1].astype(float) * c[:, None] ** 3
    np.testing.assert_allclose(pop["p_volume"][1], pv / pv.sum(), atol=1e-6)


def _weibull_exact(mean, std):
    """D10/D50/D90 by volume of the Weibull of this mean and std: numerical shape, incomplete-gamma inverse."""
    from scipy import optimize, special

    cv2 = (std / mean) ** 2
    k = optimize.brentq(lambda k: special.gamma(1 + 2 / k) / special.gamma(1 + 1 / k) ** 2 - 1 - cv2, 0.2, 200.0)
    law = stats.weibull_min(k, scale=mean / special.gamma(1 + 1 / k))
    assert law.mean() == pytest.approx(mean) and law.std() == pytest.approx(std)
    return law


@pytest.mark.parametrize("cv", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_weibull_closed_form_against_the_exact_law(cv):
    """The closed form (Justus shape, Wilson-Hilferty quantile) within 2.5 % of numerically integrated
    volume-weighted quantiles, area-weighted mean and mode of the Weibull with the same mean and std."""
    mean = 50.0
    law = _weibull_exact(mean, cv * mean)
    got = st.weibull_size_stats(np.array(mean), np.array(cv * mean))
    s = np.linspace(1e-6, law.ppf(1 - 1e-13), 400_001)
    f = law.pdf(s)
    cum3 = integrate.cumulative_trapezoid(s**3 * f, s, initial=0.0)
    cum2 = integrate.cumulative_trapezoid(s**2 * f, s, initial=0.0)
    for key, q in st.DVALUE_QUANTILES.items():
        assert float(got[key]) == pytest.approx(np.interp(q, cum3 / cum3[-1], s), rel=0.025), key
    assert float(got["s_mean_area_um"]) == pytest.approx(cum3[-1] / cum2[-1], rel=0.025)
    assert float(got["s_mode_area_um"]) == pytest.approx(s[np.argmax(s**2 * f)], rel=0.025)


def test_weibull_closed_form_accepts_casadi_symbols():
    ca = pytest.importorskip("casadi")
    m, s = ca.SX.sym("m"), ca.SX.sym("s")
    out = st.weibull_size_stats(m, s)
    f = ca.Function("f", [m, s], [out[k] for k in st.SIZE_STAT_NAMES])
    for mean, std in ((65.0, 40.0), (40.0, 4.0), (30.0, 45.0)):  # the last below the shape floor k = 1
        want = st.weibull_size_stats(np.array(mean), np.array(std))
        np.testing.assert_allclose([float(v) for v in f(mean, std)], [float(want[k]) for k in st.SIZE_STAT_NAMES],
                                   rtol=1e-12)


@pytest.mark.slow
def test_moment_model_and_filter_report_the_same_dvalues():
    """The filter's size statistics are the moment model's closed form over its particles."""
    from bmctl.estimate import FilterSettings, ParticleFilter
    from bmctl.moments.model import make_moment_model
    from bmctl.plant import default_card

    model = make_moment_model(default_card(), coeffs="defaults")
    x = np.array([65.0, 40.0, 0.16, 0.16, 40.0, 0.1])
    out = model.outputs(x)
    want = st.law_size_stats(np.array(65.0), np.array(40.0))
    for k in st.SIZE_STAT_NAMES:
        assert float(out[k]) == pytest.approx(float(want[k]), rel=1e-6)  # projection: identity to 1e-6
    pf = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=64), x0=x)
    est = pf.estimate()
    mean, lo, hi = est.size_stats["d50_um"]
    d50 = model.outputs(pf.X)["d50_um"]
    assert lo <= mean <= hi and d50.min() <= lo and hi <= d50.max()
    assert est.as_dict()["d50_um_q95"] == hi


def test_ndtri_table_is_scipys_and_the_normal_law():
    """The D-value quantiles' table equals scipy's ndtri to the last bit, and Phi(z) = q (erf law)."""
    import math

    from scipy.special import ndtri as scipy_ndtri

    from bmctl.stats import _NDTRI, ndtri

    for q, z in _NDTRI.items():
        assert z == float(scipy_ndtri(q)), q
        assert abs(0.5 * (1 + math.erf(z / math.sqrt(2))) - q) < 1e-15
    assert ndtri(0.25) == float(scipy_ndtri(0.25))  # off the table: scipy


@pytest.mark.parametrize("sigma", [0.7, 3.0, 12.5])
@pytest.mark.parametrize("n", [5, 40, 900])
def test_gaussian_smooth_is_scipys_gaussian_filter1d(sigma, n):
    from scipy.ndimage import gaussian_filter1d

    from bmctl.stats import gaussian_smooth

    h = np.random.default_rng(n).poisson(5.0, n).astype(float)
    np.testing.assert_allclose(gaussian_smooth(h, sigma), gaussian_filter1d(h, sigma, mode="constant"),
                               rtol=1e-12, atol=1e-14)
