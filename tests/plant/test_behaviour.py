"""The paper's Sec. 4.2 claims, as seeded tests on the three model cards (docs/fidelity.md).

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

from ..conftest import CARDS, card_path

M = 20000
SEED = 2024

#: every test reads the 12 h runs of the module fixture (about 15 s under load): full run only
pytestmark = pytest.mark.slow


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


def _deviation_reasons() -> tuple[str, str]:
    """The two known deviations, with the current numbers of ``results/fidelity_table.json`` (the same
    runs: M 20000, seed 2024, written by ``python benchmarks/fidelity_table.py``)."""
    import json

    from ..conftest import ROOT

    try:
        d = json.loads((ROOT / "results" / "fidelity_table.json").read_text(encoding="utf-8"))
        nq = json.loads((ROOT / "results" / "fidelity_table_no_equiaxing.json").read_text(encoding="utf-8"))
        cards = ("lab", "400", "1:3")
        mode = " / ".join(f"{d[c]['derived']['s_mode_max_1_6h']:.1f}" for c in cards)
        area = " / ".join(f"{d[c]['derived']['s_mode_area_um']['value']:.0f}" for c in cards)
        pf = d["lab"]["derived"]["fracture_probability_2h"]
        r = ", ".join(f"{c} {d[c]['derived']['r_mean']['at_6h']:.3f} -> {d[c]['derived']['r_mean']['at_12h']:.3f}"
                      for c in cards)
        runaway = " / ".join(f"{nq[c]['derived']['r_mean']['at_12h']:.2f}" for c in cards)
    except (OSError, KeyError, ValueError):  # a results file missing or changed: the reasons without numbers
        mode = area = r = runaway = "see results/fidelity_table.json"
        pf = {"40": float("nan"), "140": float("nan")}
    mode_reason = (f"known deviation (docs/fidelity.md, item 4): the number-weighted mode falls from 40.5 um in the "
                   f"first hour (at most {mode} um in 1-6 h on the lab, 400 rpm and 1:3 cards): binary coagulation "
                   f"from a narrow start keeps monomers the most numerous class and the per-impact fracture "
                   f"probability climbs from {pf['40']:.3f} at 40 um to {pf['140']:.2f} at 140 um (a fracture "
                   f"ceiling); the area-weighted mode does rise (to {area} um)")
    r_reason = (f"known deviation (docs/fidelity.md, item 10): the mean of r falls late (6 -> 12 h: {r}) because r "
                f"is made by bonds and fractures (rates ~ s^2) and removed by bmctl's own equiaxing law (not the "
                f"paper's; rate ~ 1/s) as the sizes fall; the paper's shape-change law (eqns 11-14) is scaled to no "
                f"measurable effect (docs/model.md); without equiaxing the mean of r runs away ({runaway} at 12 h)")
    return mode_reason, r_reason


_MODE_REASON, _R_REASON = _deviation_reasons()


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


@pytest.mark.xfail(strict=True, reason=_MODE_REASON)
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


@pytest.mark.xfail(strict=True, reason=_R_REASON)
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


@pytest.mark.slow
@pytest.mark.parametrize("name", CARDS)
def test_area_weighted_mode_rises_then_falls(runs, name):
    """bmctl's statement (not the paper's): the area-weighted mode (weight s^2, where a micrograph's area
    fraction peaks) rises within 1-3 h and has fallen by 12 h, on every card (M 20000, seed 2024)."""
    mode = series(runs[name], "s_mode_area_um")
    peak = mode[1:4].max()
    assert peak > mode[0] + 15.0, f"area-weighted mode {mode[:4]} um"
    assert mode[12] < 0.75 * peak, f"area-weighted mode at 12 h {mode[12]} um, peak {peak} um"


@pytest.mark.slow
@pytest.mark.parametrize("name", CARDS)
def test_volume_dvalues_ordered_and_above_number_mean(runs, name):
    """D10 <= D50 <= D90 at every hour, and D50 (by volume) >= the number mean once milling has spread the sizes."""
    d10, d50, d90 = (series(runs[name], k) for k in ("d10_um", "d50_um", "d90_um"))
    assert np.all(d10 <= d50) and np.all(d50 <= d90)
    assert np.all(d50[1:] > series(runs[name], "s_mean_um")[1:])
