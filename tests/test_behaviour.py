"""The paper's Sec. 4.2 claims, as seeded tests on the three model cards.

(a) mean, std and mode of s rise in the first hours; mean and mode fall again later, peak in 1-6 h;
(b) for t > 0 the size distribution is fitted better by a log-normal than by a normal;
(c) the mode of r stays below 0.05 while the mean and std of r grow slowly;
(d) 400 rpm: more bonding and fracture per milling hour than 300 rpm; 1:3 fewer than 1:1.
"""

import numpy as np
import pytest
from scipy import stats

from bmctl.config import card_schedule, load_card
from bmctl.plant.plant import Plant

from .conftest import CARDS, card_path

M = 20000
SEED = 2024


@pytest.fixture(scope="module")
def runs():
    out = {}
    for name in CARDS:
        card = load_card(card_path(name))
        segments = card_schedule(card, 12.0)
        plant = Plant(card, np.random.default_rng(SEED), M)
        samples = []
        recs = plant.run_schedule(segments, 1.0, on_record=lambda p: samples.append(p.s.copy()))
        milling_h = sum(h for h, rpm in segments if rpm > 0)
        out[name] = dict(recs=recs, samples=dict(enumerate(samples)), counts=plant.counts, milling_h=milling_h)
    return out


def series(run, key):
    return np.array([r.moments[key] for r in run["recs"]])


@pytest.mark.parametrize("name", CARDS)
def test_a_mean_and_std_rise_then_mean_falls(runs, name):
    mean = series(runs[name], "s_mean_um")
    std = series(runs[name], "s_std_um")
    peak = int(np.argmax(mean))
    assert 1 <= peak <= 6, f"peak of mean s at {peak} h"
    assert mean[peak] > 1.1 * mean[0]
    assert std[1:4].max() > 3 * std[0]
    assert mean[-1] < 0.9 * mean[peak]


@pytest.mark.parametrize("name", CARDS)
def test_a_mode_falls_later(runs, name):
    mode = series(runs[name], "s_mode_um")
    assert mode[-1] < mode[1:7].max()


@pytest.mark.xfail(strict=True, reason="known deviation (docs/calibration.md): the bonding "
                   "kernel (15) favours the big particles and fracture (20) halves the 40 um ones, so the mean grows "
                   "through a long tail of welded particles while the number density keeps its peak at 30-40 um; "
                   "the smoothed mode stays at 24-38 um for 1-6 h on every card, never above 42.5 um; weakening fracture "
                   "until the mode rises breaks claim (b) first")
@pytest.mark.parametrize("name", CARDS)
def test_a_mode_rises_first(runs, name):
    mode = series(runs[name], "s_mode_um")
    assert mode[1:7].max() > mode[0] + 2.0


@pytest.mark.parametrize("name", CARDS)
def test_b_lognormal_beats_normal(runs, name):
    for t, s in runs[name]["samples"].items():
        if t == 0:
            continue
        x = np.random.default_rng(t).choice(s, 3000, replace=False) * 1e6
        ll_norm = stats.norm.logpdf(x, x.mean(), x.std()).sum()
        lx = np.log(x)
        ll_lognorm = stats.norm.logpdf(lx, lx.mean(), lx.std()).sum() - lx.sum()
        assert ll_lognorm > ll_norm, f"t={t} h"


@pytest.mark.parametrize("name", CARDS)
def test_c_r_mode_low_mean_and_std_grow_slowly(runs, name):
    mode = series(runs[name], "r_mode")
    mean = series(runs[name], "r_mean")
    std = series(runs[name], "r_std")
    assert np.all(mode < 0.05)
    assert mean[-1] > mean[0] and std[-1] > std[0]
    assert np.all(np.diff(mean) < 0.2) and np.all(mean < 0.5)


@pytest.mark.xfail(strict=True, reason="known deviation (docs/calibration.md): r is made by "
                   "bonds and fractures (rates ~ s^2) and removed by rounding (rate ~ 1/s), so when the sizes fall "
                   "after the peak the mean of r falls with them (lab 0.18 -> 0.11 from 6 to 12 h); switching rounding "
                   "off by 12 h on the lab card lets r run away (r mode > 0.4) on the faster-hardening 400 rpm card")
@pytest.mark.parametrize("name", CARDS)
def test_c_mean_r_keeps_growing_late(runs, name):
    mean = series(runs[name], "r_mean")
    assert mean[-1] >= mean[6]


def test_d_event_rates_order(runs):
    rate = {n: (runs[n]["counts"].bonds / runs[n]["milling_h"], runs[n]["counts"].fractures / runs[n]["milling_h"])
            for n in CARDS}
    lab, fan, hj = (rate[n] for n in CARDS)
    assert fan[0] > lab[0] and fan[1] > lab[1]
    assert hj[0] < lab[0] and hj[1] < lab[1]


@pytest.mark.parametrize("name", CARDS)
def test_physically_sane(runs, name):
    """Sizes stay in the micrograph range; the vial warms by a few tens of K at 300 rpm."""
    mean = series(runs[name], "s_mean_um")
    assert np.all((mean > 10) & (mean < 300))
    rise = max(r.temperature_c for r in runs[name]["recs"]) - runs[name]["recs"][0].temperature_c
    assert 0 < rise < 120
    if "300rpm" in name:
        assert 15 < rise < 80
