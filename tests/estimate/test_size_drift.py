"""The particle filter's offset-free size drift (``size_drift_prior_per_h``).

Each particle carries a drift rate b of ln(s_mean) per milling hour that the moment model misses;
the prediction multiplies s_mean and s_std by exp(b * milling hours) (the size law's spread kept)
and leaves a rest alone. Closed-loop evidence: docs/control.md (hidden mills).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.estimate.filter import FilterSettings, ParticleFilter

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


def _pair(model, b):
    """A filter with drift b on every particle and one without, same particles and parameters."""
    on = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=64, size_drift_prior_per_h=0.1))
    off = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=64))
    off.X, off.logP = on.X.copy(), on.logP.copy()
    on.drift = np.full(64, b)
    return on, off


@pytest.mark.parametrize("u, dt_h, milled_h", [((300.0, 0.5), 1.0, 0.5), ((300.0, 1.0), 0.25, 0.25),
                                                ((0.0, 1.0), 1.0, 0.0), ((300.0, 0.0), 2.0, 0.0)])
def test_drift_scales_the_size_moments_by_milling_hours(model, u, dt_h, milled_h):
    b = 0.12
    on, off = _pair(model, b)
    on.predict(u, dt_h)
    off.predict(u, dt_h)
    f = math.exp(b * milled_h)
    assert np.allclose(on.X[:, 0], np.clip(off.X[:, 0] * f, 0.1, 1e5), rtol=1e-12)
    assert np.allclose(on.X[:, 1] / on.X[:, 0], off.X[:, 1] / off.X[:, 0], rtol=1e-9)  # the CV is kept
    assert np.array_equal(on.X[:, 2:], off.X[:, 2:])  # shape, temperature and hardening untouched


def test_drift_state_survives_and_is_reported(model):
    st = FilterSettings(n_particles=64, size_drift_prior_per_h=0.1, size_drift_walk_per_sqrt_h=0.05)
    pf = ParticleFilter(model, np.random.default_rng(2), st)
    prior = pf.drift.copy()
    assert 0.05 < prior.std() < 0.2  # drawn from N(0, 0.1^2)
    pf.predict((300.0, 1.0), 1.0)
    assert not np.array_equal(pf.drift, prior)  # it walks while milling
    walked = pf.drift.copy()
    pf.predict((0.0, 0.0), 1.0)
    assert np.array_equal(pf.drift, walked)  # and not at rest
    est = pf.estimate().as_dict()
    assert est["size_drift_per_h_q05"] <= est["size_drift_per_h"] <= est["size_drift_per_h_q95"]
    twin = ParticleFilter(model, np.random.default_rng(9), st)
    twin.set_state(pf.get_state())
    assert np.array_equal(twin.drift, pf.drift)
    legacy = {k: v for k, v in pf.get_state().items() if k != "drift"}  # a state written before the drift
    twin.set_state(legacy)
    assert np.all(twin.drift == 0.0)
    plain = ParticleFilter(model, np.random.default_rng(2), FilterSettings(n_particles=64))
    assert "size_drift_per_h" not in plain.estimate().as_dict()  # off by default


def test_campaign_filter_is_offset_free():
    from bmctl.campaign.workflow import CAMPAIGN_FILTER

    st = FilterSettings(**CAMPAIGN_FILTER)
    assert st.size_drift_prior_per_h > 0 and st.size_drift_walk_per_sqrt_h > 0
