"""The moment model's optional third multiplier, ``energy_mult``, and the filter that carries it.

``energy_mult`` scales the card's mean impact energy per particle (``e_max_J_per_um2``): what a
different ball size, ball count or powder mass changes most (docs/estimation.md, "A third
multiplier"). The checks compare against an independent construction: the same model with the
card constant itself scaled.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bmctl.estimate.filter import FilterSettings, ParticleFilter

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


def test_energy_mult_one_is_the_two_multiplier_model_bit_for_bit(model):
    X = np.repeat(model.x0()[None], 4, axis=0)
    u = np.array([[120.0, 1.0], [300.0, 0.5], [450.0, 1.0], [0.0, 1.0]])
    two = model.step(X, u, 0.5, np.ones((4, 2)))
    three = model.step(X, u, 0.5, np.ones((4, 3)))
    assert np.array_equal(two, three)


@pytest.mark.parametrize("em", [0.75, 1.3])
def test_energy_mult_is_the_card_with_its_impact_energy_scaled(model, em):
    from bmctl.moments.model import MomentModel

    scaled = MomentModel(model.card, model.coeffs)
    scaled.const = dataclasses.replace(model.const, e_max_J_per_um2=model.const.e_max_J_per_um2 * em)
    X = np.repeat(model.x0()[None], 3, axis=0)
    u = np.array([[150.0, 1.0], [300.0, 1.0], [420.0, 0.4]])
    for _ in range(3):  # 1.5 h, in three steps on both
        Xa = model.step(X, u, 0.5, np.tile([1.2, 0.8, em], (3, 1)))
        Xb = scaled.step(X, u, 0.5, np.tile([1.2, 0.8], (3, 1)))
        np.testing.assert_allclose(Xa, Xb, rtol=1e-12)
        X = Xa
    # a single trajectory (the compiled path takes two multipliers) goes the numpy way, same numbers
    one = model.simulate(model.x0(), [[300.0, 1.0]] * 3, 0.5, p=[1.2, 0.8, em])
    ref = scaled.simulate(model.x0(), [[300.0, 1.0]] * 3, 0.5, p=[1.2, 0.8])
    np.testing.assert_allclose(one, ref, rtol=1e-9)


def test_more_impact_energy_per_particle_fractures_more(model):
    """At a speed where fracture wins, more energy per particle ends smaller (eqn 20's barrier)."""
    X = np.repeat(model.x0()[None], 3, axis=0)
    P = np.array([[1.0, 1.0, 0.8], [1.0, 1.0, 1.0], [1.0, 1.0, 1.25]])
    for _ in range(4):
        X = model.step(X, np.array([400.0, 1.0]), 0.5, P)
    assert X[0, 0] > X[1, 0] > X[2, 0]


def test_filter_carries_energy_mult_only_when_asked(model):
    off = ParticleFilter(model, np.random.default_rng(3), FilterSettings(n_particles=200))
    on = ParticleFilter(model, np.random.default_rng(3), FilterSettings(n_particles=200, energy_prior_log_std=0.25))
    assert off.param_names == ("gamma_mult", "delta_mult") and off.P.shape == (200, 2)
    assert on.param_names == ("gamma_mult", "delta_mult", "energy_mult") and on.P.shape == (200, 3)
    # the prior: log energy_mult ~ N(0, 0.25^2); 200 draws
    sd = float(np.std(on.logP[:, 2], ddof=1))
    assert 0.25 * 0.8 < sd < 0.25 * 1.2
    assert abs(float(np.mean(on.logP[:, 2]))) < 3 * 0.25 / np.sqrt(200)
    on.predict((300.0, 1.0), 0.5)
    est = on.estimate()
    assert "energy_mult" in est.names
    again = ParticleFilter(model, np.random.default_rng(3), FilterSettings(n_particles=200, energy_prior_log_std=0.25))
    again.predict((300.0, 1.0), 0.5)
    again.estimate()  # applies the deferred process noise, as on's estimate did
    assert np.array_equal(again.X, on.X) and np.array_equal(again.logP, on.logP)


def test_planner_takes_three_multipliers_and_the_nlp_two(model):
    from bmctl.control.base import check_p
    from bmctl.errors import InputError

    assert check_p(model, [1.0, 1.0, 0.9]).shape == (3,)
    with pytest.raises(InputError, match="energy_mult"):
        check_p(model, [1.0, 1.0, 0.9, 1.0])
