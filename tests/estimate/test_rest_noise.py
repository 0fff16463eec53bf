"""The particle filter's moment noise at rest (``rest_noise_fraction``).

The powder does not change while the mill rests, so with a small ``rest_noise_fraction`` the
moments take discrepancy noise for the milled hours and a small share of the rest, and hourly
samples of a resting mill average out: the estimate's error after k samples falls like the sampling
error of one sample over sqrt(k) (with the wall-clock noise, 1, it stays near one sample's; with
none at all, 0, the reweighted cloud degenerates).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.estimate.filter import N_MOMENTS, FilterSettings, ParticleFilter

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


@pytest.mark.parametrize("u, dt_h, frac, expected_h", [((300.0, 0.5), 1.0, 0.0, 0.5), ((300.0, 0.5), 1.0, 0.2, 0.6),
                                                       ((0.0, 1.0), 2.0, 0.0, 0.0), ((300.0, 1.0), 0.5, 0.0, 0.5),
                                                       ((300.0, 0.25), 2.0, 1.0, 2.0)])
def test_discrepancy_time_counts_milled_hours_and_a_share_of_the_rest(model, u, dt_h, frac, expected_h):
    pf = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=32, rest_noise_fraction=frac))
    pf.predict(u, dt_h)
    assert pf.pending_model_h == pytest.approx(expected_h, abs=1e-12)
    assert pf.pending_h == pytest.approx(dt_h, abs=1e-12)  # the vial's gain walks on wall hours


@pytest.mark.parametrize("frac, moved", [(0.0, False), (1.0, True)])
def test_a_rest_leaves_the_moments_alone_at_fraction_zero(model, frac, moved):
    pf = ParticleFilter(model, np.random.default_rng(1), FilterSettings(n_particles=64, rest_noise_fraction=frac))
    pf.predict((300.0, 1.0), 1.0)
    pf.update(temperature_c=pf.reading_prediction()[0])  # the milled hour's noise spent
    pf.predict((0.0, 0.0), 3.0)
    noisy, _ = pf._with_pending_noise()
    assert (not np.array_equal(pf.X[:, :N_MOMENTS], noisy[:, :N_MOMENTS])) == moved


def test_state_without_the_model_clock_reads_the_wall_clock(model):
    pf = ParticleFilter(model, np.random.default_rng(2), FilterSettings(n_particles=32, rest_noise_fraction=0.0))
    pf.predict((300.0, 0.5), 1.0)
    state = pf.get_state()
    del state["pending_model_h"]  # a state saved before the setting existed
    pf.set_state(state)
    assert pf.pending_model_h == pf.pending_h == 1.0


def _rest_errors(model, frac: float, k: int = 8, reps: int = 6, n: int = 300, sigma: float = 0.3):
    """Relative errors of the estimated s_mean after k samples of a resting population."""
    out = []
    for rep in range(reps):
        g = np.random.default_rng(100 + rep)
        st = FilterSettings(n_particles=400, rest_noise_fraction=frac, initial_spread=0.1)
        x0 = np.asarray(model.x0(), dtype=float).copy()
        pf = ParticleFilter(model, np.random.default_rng(200 + rep), st, x0=x0)
        x0[1] = x0[0] * math.sqrt(math.expm1(sigma**2))  # the prior's spread is the powder's
        s_mean = float(x0[0]) * 1.04  # the powder: 4 % off the prior's centre
        mu = math.log(s_mean) - 0.5 * sigma**2  # lognormal with that mean
        for _ in range(k):
            pf.predict((0.0, 0.0), 1.0)
            est = pf.update(s_um=g.lognormal(mu, sigma, n), r=g.uniform(0.0, 0.1, n))
        out.append(est.as_dict()["s_mean_um"] / s_mean - 1.0)
    return np.array(out)


def test_hourly_samples_of_a_resting_mill_average_out(model):
    k, n, sigma = 8, 300, 0.3
    one = math.sqrt(math.expm1(sigma**2) / n)  # relative sd of one sample's mean (lognormal)
    err = _rest_errors(model, 0.02, k, n=n, sigma=sigma)  # the campaign's setting
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < 2.0 * one / math.sqrt(k), (rms, one)
    for frac in (1.0, 0.0):  # the bar tells: wall-clock noise forgets, no noise degenerates
        other = float(np.sqrt(np.mean(_rest_errors(model, frac, k, n=n, sigma=sigma) ** 2)))
        assert other > 2.0 * one / math.sqrt(k), (frac, other)
