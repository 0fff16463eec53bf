"""The estimators' ``predict`` as a library user calls it: negative or non-finite hours and an
input that is not (rpm, milling) are refused naming the argument (a negative interval used to be
dropped without a word, a scalar input failed with an IndexError deep in the model)."""

import numpy as np
import pytest

from bmctl.errors import InputError
from bmctl.estimate import FilterSettings, ParticleFilter, make_estimator
from bmctl.moments import make_moment_model


@pytest.fixture(scope="module")
def model():
    return make_moment_model("models/alni-1to1-300rpm-lab.toml")


@pytest.fixture(params=["pf", "ukf"])
def est(request, model):
    return make_estimator(request.param, model, np.random.default_rng(0), n_particles=20)


@pytest.mark.parametrize("dt_h", [-1.0, float("nan"), float("inf")])
def test_predict_refuses_hours_that_are_negative_or_not_finite(est, dt_h):
    t0 = est.t_h
    with pytest.raises(InputError, match="dt_h: must be a finite number of hours >= 0"):
        est.predict((300.0, 1.0), dt_h)
    assert est.t_h == t0


@pytest.mark.parametrize("u", [300.0, (300.0, 1.0, 2.0), (-5.0, 1.0), (300.0, 3.0), (float("nan"), 1.0)])
def test_predict_refuses_an_input_that_is_not_rpm_and_milling(est, u):
    with pytest.raises(InputError, match=r"u: must be \(rpm, milling\)"):
        est.predict(u, 0.5)


def test_predict_over_zero_hours_does_nothing(est):
    t0 = est.t_h
    est.predict((300.0, 1.0), 0.0)
    assert est.t_h == t0


def test_particle_filter_refuses_a_seed_for_its_generator(model):
    with pytest.raises(TypeError, match="rng: must be a numpy.random.Generator"):
        ParticleFilter(model, 5, FilterSettings(n_particles=20))


def test_rounding_within_input_rounding_passes_as_it_always_has(est):
    """A solver's bound violation (milling 1 + 1e-9) or a difference of times just below 0 is not an
    error: refusing it would stop a trial that used to run."""
    t0 = est.t_h
    est.predict((300.0, 1.0), -1e-12)  # taken as 0: nothing
    assert est.t_h == t0
    est.predict((300.0 - 0.0, 1.0 + 1e-9), 0.5)
    est.predict((-1e-9, -1e-9), 0.5)
    assert est.t_h == pytest.approx(t0 + 1.0)
