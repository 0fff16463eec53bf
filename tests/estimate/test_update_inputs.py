"""The estimators' ``update``, ``resample`` and ``make_estimator`` refuse what ``run_filter`` refuses, naming
the argument, before anything changes; a sample no particle can explain is flagged ``degenerate``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.errors import InputError
from bmctl.estimate import FilterSettings, ParticleFilter, make_estimator
from bmctl.estimate.resampling import SCHEMES, effective_sample_size, resample
from bmctl.estimate.run import collapsed

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments import make_moment_model

    return make_moment_model(LAB)


def _estimator(model, kind):
    est = make_estimator(kind, model, np.random.default_rng(0), n_particles=100)
    est.predict((300.0, 1.0), 1.0)
    return est


def _same_state(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for k in a:
        if isinstance(a[k], np.ndarray):
            if not np.array_equal(a[k], b[k]):
                return False
        elif a[k] != b[k]:
            return False
    return True


def _sample(n=100, seed=1):
    g = np.random.default_rng(seed)
    return g.lognormal(np.log(45.0), 0.3, n), g.uniform(0.0, 0.1, n)


# --- the vial-temperature reading --------------------------------------------------------------
@pytest.mark.parametrize("kind", ["pf", "ukf"])
@pytest.mark.parametrize("reading", [-1000.0, -60.0, 1e6, 700.0, math.nan, math.inf])
def test_update_refuses_a_reading_run_filter_refuses(model, kind, reading):
    """-1000 °C (below absolute zero) was weighed in, 1e6 °C sent the UKF's s_mean to 1e5 µm, NaN was a
    ValueError."""
    est = _estimator(model, kind)
    before = est.get_state()
    with pytest.raises(InputError, match=r"^temperature_c: reading .* outside \[-50, 660\.3\] °C"):
        est.update(temperature_c=reading)
    assert _same_state(before, est.get_state())


@pytest.mark.parametrize("kind", ["pf", "ukf"])
@pytest.mark.parametrize("reading", ["30", True])
def test_update_refuses_a_reading_that_is_no_number(model, kind, reading):
    with pytest.raises(TypeError, match="^temperature_c: a reading is a number of degC"):
        _estimator(model, kind).update(temperature_c=reading)


@pytest.mark.parametrize("kind", ["pf", "ukf"])
def test_update_takes_readings_inside_the_range(model, kind):
    for reading in (-50.0, 31.0, np.float32(40.0), 660.3):
        est = _estimator(model, kind).update(temperature_c=reading)
        assert np.all(np.isfinite(est.mean))


# --- the sample --------------------------------------------------------------------------------
def _bad_samples():
    s, r = _sample()
    return [
        ("nan size", np.r_[s[:-1], np.nan], r, r"^s_um, r: particle 100: s_um = nan outside \[0\.001, 10000\] µm"),
        ("negative size", -s, r, r"^s_um, r: particle 1: s_um = -\S+ outside"),
        ("1e9 um", np.full(50, 1e9), r[:50], r"^s_um, r: particle 1: s_um = 1e\+09 outside \[0\.001, 10000\] µm"),
        ("r = 1", s, np.r_[r[:-1], 1.0], r"^s_um, r: particle 100: r = 1 outside \[0, 1\)"),
        ("r nan", s, np.r_[np.nan, r[1:]], r"^s_um, r: particle 1: r = nan outside \[0, 1\)"),
        ("lengths", s, r[:-1], r"^s_um, r: a sample needs one or more particles with one s and one r each"),
        ("empty", [], [], r"^s_um, r: a sample needs one or more particles"),
        ("no r", s, None, r"^s_um, r: a sample needs one or more particles"),
        ("no s", None, r, r"^s_um, r: a sample needs one or more particles .* \(got r only\)"),  # r was ignored
    ]


@pytest.mark.parametrize("kind", ["pf", "ukf"])
@pytest.mark.parametrize("case", _bad_samples(), ids=lambda c: c[0])
def test_update_refuses_a_sample_run_filter_refuses(model, kind, case):
    """NaN, negative sizes, unequal lengths and empty samples were plain ValueErrors; 1e9 µm was taken."""
    _, s, r, needle = case
    est = _estimator(model, kind)
    before = est.get_state()
    with pytest.raises(InputError, match=needle):
        est.update(s, r, temperature_c=35.0)  # a good reading beside it is not weighed in either
    assert _same_state(before, est.get_state())


@pytest.mark.parametrize("kind", ["pf", "ukf"])
def test_update_refuses_a_sample_that_is_no_numbers(model, kind):
    with pytest.raises(TypeError, match="^s_um, r: a sample is two arrays of numbers"):
        _estimator(model, kind).update(["a", "b"], [0.1, 0.1])


@pytest.mark.parametrize("kind", ["pf", "ukf"])
def test_update_takes_sizes_at_the_ends_of_the_range(model, kind):
    s, r = _sample(20)
    s[0], s[1] = 1e-3, 1e4
    assert np.all(np.isfinite(_estimator(model, kind).update(s, r).mean))


# --- the degenerate flag -----------------------------------------------------------------------
@pytest.mark.parametrize("proposal", ["guided", "bootstrap"])
def test_a_sample_no_particle_can_explain_is_degenerate_and_keeps_the_prior_weights(model, proposal):
    """Every particle's size likelihood at the floor (5 mm particles from a 40 µm powder of cv 0.1): the
    floored log-probabilities left finite weights (the proposal's correction), reported as a healthy update."""
    pf = ParticleFilter(model, np.random.default_rng(0),
                        FilterSettings(n_particles=200, proposal=proposal, feed_log_std=0.0))
    pf.predict((0.0, 0.0), 0.5)
    prior = pf.logw.copy()
    est = pf.update(np.full(50, 5000.0), np.random.default_rng(1).uniform(0.0, 0.1, 50))
    assert est.degenerate and pf.n_degenerate == 1 and collapsed(est)
    assert np.array_equal(pf.logw, prior) and est.ess == pytest.approx(200.0)


def test_an_ordinary_sample_is_not_degenerate(model):
    pf = make_estimator("pf", model, np.random.default_rng(0), n_particles=200)
    pf.predict((300.0, 1.0), 1.0)
    est = pf.update(*_sample())
    assert not est.degenerate and pf.n_degenerate == 0


# --- make_estimator ----------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 0, -5, 9])
def test_make_estimator_names_too_few_particles(model, n):
    """A raw pydantic ValidationError before."""
    with pytest.raises(InputError, match=rf"^n_particles: the particle filter needs 10 or more particles \(got {n}\)"):
        make_estimator("pf", model, np.random.default_rng(0), n_particles=n)


def test_make_estimator_takes_ten_particles(model):
    assert make_estimator("pf", model, np.random.default_rng(0), n_particles=10).settings.n_particles == 10


# --- resampling --------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("weights", [[0.0, 0.0, 0.0], [math.nan, 1.0, 1.0], [math.inf, 1.0, 1.0], [-1.0, 1.0, 1.0],
                                     [], [[0.5, 0.5]]], ids=["zeros", "nan", "inf", "negative", "empty", "2-D"])
def test_resample_refuses_weights_that_are_no_distribution_in_every_scheme(scheme, weights):
    """All-zero, NaN, inf and negative weights gave all-zero indices (residual: a numpy error), none an IndexError."""
    with pytest.raises(InputError, match="^weights: "):
        resample(np.array(weights, dtype=float), np.random.default_rng(0), scheme)


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("rng", [None, np.random.RandomState(0), 0])
def test_resample_takes_only_a_numpy_generator(scheme, rng):
    with pytest.raises(TypeError, match="^rng: must be a numpy.random.Generator"):
        resample(np.full(4, 0.25), rng, scheme)


@pytest.mark.parametrize("weights", [np.zeros(3), np.array([math.nan, 0.5, 0.5]), np.array([])])
def test_effective_sample_size_refuses_weights_that_are_no_distribution(weights):
    """ESS of all-zero weights was inf."""
    with pytest.raises(InputError, match="^weights: "):
        effective_sample_size(weights)


def test_resampling_of_valid_weights_is_unchanged():
    """Zero weights among positive ones stay valid; the indices are those of the inverse-CDF formulas."""
    w = np.random.default_rng(5).gamma(0.5, size=50)
    w[[3, 7]] = 0.0
    w /= w.sum()
    c = np.cumsum(w / w.sum())
    c[-1] = 1.0
    N = w.size

    def inv(pos):
        return np.minimum(np.searchsorted(c, pos, side="right"), N - 1)

    g = np.random.default_rng(9)
    assert np.array_equal(resample(w, np.random.default_rng(9), "systematic"), inv((g.random() + np.arange(N)) / N))
    g = np.random.default_rng(9)
    assert np.array_equal(resample(w, np.random.default_rng(9), "stratified"), inv((g.random(N) + np.arange(N)) / N))
    g = np.random.default_rng(9)
    assert np.array_equal(resample(w, np.random.default_rng(9), "multinomial"), inv(g.random(N)))
    assert effective_sample_size(w) == 1.0 / np.sum(np.square(w))


# --- the estimators' own model steps -----------------------------------------------------------
def test_the_ukfs_sigma_points_outside_the_models_public_domain_still_step(model):
    """A wide temperature prior puts sigma points below absolute zero, which ``MomentModel.step`` refuses
    from a user; the filter's own step runs them as before (a failed step keeps its point)."""
    from bmctl.estimate import UKFEstimator, UKFSettings

    f = UKFEstimator(model, np.random.default_rng(0), UKFSettings(initial_temperature_std_c=200.0))
    f.predict((300.0, 1.0), 0.5)
    assert np.all(np.isfinite(f.estimate().mean)) and np.all(np.isfinite(f.cov))
