"""A sample of the feed (``feed_log_std``): taken before any milling, it reads the starting powder.

The card's ``[initial]`` holds the starting powder within ``initial_spread`` (2 %). A user's feed
often differs from it; a sample of that feed must move the estimate to what the sample shows, not
collapse the particle cloud onto the particle nearest to it (with the parameters' spread gone too).
The truth here is the lognormal law the sample is drawn from: mean = median * exp(sigma^2 / 2).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.estimate.filter import FilterSettings, ParticleFilter

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
FEED_MEDIAN_UM, FEED_SIGMA = 60.0, 0.3  # the card says 40 um
TRUTH_UM = FEED_MEDIAN_UM * math.exp(FEED_SIGMA**2 / 2)


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


def _feed(seed: int, n: int = 300):
    g = np.random.default_rng(seed)
    return g.lognormal(math.log(FEED_MEDIAN_UM), FEED_SIGMA, n), g.beta(2.0, 40.0, n)


def _read_feed(model, seed: int, feed_log_std: float):
    pf = ParticleFilter(model, np.random.default_rng(100 + seed),
                        FilterSettings(n_particles=1000, feed_log_std=feed_log_std))
    s, r = _feed(seed)
    return pf.update(s_um=s, r=r).as_dict(), float(np.mean(s))


@pytest.mark.parametrize("feed_log_std", [1.0, 0.0])
def test_a_sample_of_the_feed_is_read_not_held_to_the_card(model, feed_log_std):
    covered, off, spread = 0, [], []
    for seed in range(20):
        est, sample_mean = _read_feed(model, seed, feed_log_std)
        covered += est["s_mean_um_q05"] <= TRUTH_UM <= est["s_mean_um_q95"]
        off.append(abs(est["s_mean_um"] / sample_mean - 1))
        spread.append(est["gamma_mult_q95"] / est["gamma_mult_q05"])
    if feed_log_std > 0:
        assert covered >= 15  # 90 % intervals over 20 feeds: P(fewer than 15) < 5 % if calibrated
        assert max(off) < 0.015  # a broad feed prior: the posterior mean is the sample's own
        assert min(spread) > 2.0  # a feed sample says nothing of gamma: its prior (log sd 0.4) stays
    else:  # the card's starting powder held within initial_spread: the cloud cannot reach 60 um
        assert covered == 0 and min(off) > 0.25


def test_a_sample_after_milling_is_unchanged_by_the_feed_prior(model):
    """The feed's prior is spent only on a sample before any milling: later samples, and so every
    campaign or trial whose first sample follows milling, are computed exactly as without it."""
    out = []
    for feed in (1.0, 0.0):
        pf = ParticleFilter(model, np.random.default_rng(7), FilterSettings(n_particles=200, feed_log_std=feed))
        pf.predict((0.0, 0.0), 0.5)  # a rest first: the feed is still what a sample would read
        assert pf.feed_open == (feed > 0)
        pf.predict((300.0, 0.5), 0.5)  # then milling
        assert not pf.feed_open
        s, r = _feed(3)
        out.append(pf.update(s_um=s * 0.9, r=r).mean)
    np.testing.assert_array_equal(out[0], out[1])


def test_the_feed_prior_is_spent_once_and_kept_in_the_state(model):
    pf = ParticleFilter(model, np.random.default_rng(8), FilterSettings(n_particles=100))
    state = pf.get_state()
    assert state["feed_open"] is True
    s, r = _feed(4)
    pf.update(s_um=s, r=r)
    assert pf.feed_open is False and pf.get_state()["feed_open"] is False
    pf.set_state(state)
    assert pf.feed_open is True
    del state["feed_open"]  # a state written before the setting: the card's feed held, as it was
    pf.set_state(state)
    assert pf.feed_open is False
