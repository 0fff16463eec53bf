"""A trial that samples the feed at 0 h (``[sampling] feed = true``), as an operator's first
``campaign sample --at-h 0``: the estimate reads a feed the card does not describe."""

from pathlib import Path

import numpy as np
import pytest

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"


def _scenario(d: Path, feed: bool) -> Path:
    """A 2-h LQR trial on the lab card whose plant's feed is 60 um (the card says 40 um)."""
    text = CARD.read_text(encoding="utf-8").replace("s_mean_um = 40.0", "s_mean_um = 60.0").replace("s_std_um = 4.0", "s_std_um = 9.0")
    assert "s_mean_um = 60.0" in text and "s_std_um = 9.0" in text
    (d / "coarse-feed.toml").write_text(text, encoding="utf-8")
    p = d / f"feed-{feed}.toml"
    p.write_text(f"""model = "{CARD}"
hours = 2.0
target = {{ s_mean_um = 40.0 }}
[scenario]
name = "coarse-feed"
description = "a 60 um feed on a card that says 40 um"
[plant]
model = "coarse-feed.toml"
particles = 2000
[sampling]
every_h = 1.0
particles = 300
feed = {str(feed).lower()}
[estimator]
particles = 300
[controller]
config = "{LQR}"
""", encoding="utf-8")
    return p


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_feed_sample_moves_the_estimate_to_the_plants_feed(tmp_path, seed):
    from bmctl.scenario import load_scenario
    from bmctl.trial import build

    loops = {f: build(load_scenario(_scenario(tmp_path, f)), tmp_path, seed) for f in (False, True)}
    truth = loops[True].mill.moments()["s_mean_um"]
    assert truth == pytest.approx(60.0, rel=0.05)  # the plant's own feed, not the card's 40 um
    assert loops[False].est["s_mean_um"] == pytest.approx(40.0, rel=0.03)  # no sample: the card's feed
    loops[True].observe_feed()
    assert loops[True].est["s_mean_um"] == pytest.approx(truth, rel=0.06)  # one 300-particle sample's reach
    assert loops[True].stats["feed_sampled"]


@pytest.mark.slow
def test_a_trial_with_a_feed_sample_is_the_same_run_as_a_campaign(tmp_path):
    from bmctl.campaign.simulated import run_as_campaign
    from bmctl.trial import run_trial

    sc = _scenario(tmp_path, True)
    summary = run_trial(sc, tmp_path / "trial", seed=5)
    assert summary["feed_sampled"]
    rows = run_as_campaign(sc, tmp_path / "campaign", seed=5)
    data = np.genfromtxt(tmp_path / "trial" / "trajectory.csv", delimiter=",", names=True, dtype=None,
                         encoding="utf-8")
    assert len(rows) == data.size == 4
    np.testing.assert_allclose([r["rpm"] for r in rows], data["rpm"], rtol=1e-5)
    np.testing.assert_allclose([r["estimate"]["s_mean_um"] for r in rows], data["est_s_mean_um"], rtol=1e-5)
    plain = run_trial(_scenario(tmp_path, False), tmp_path / "plain", seed=5)
    assert not plain["feed_sampled"]
    first_plain = np.genfromtxt(tmp_path / "plain" / "trajectory.csv", delimiter=",", names=True, dtype=None,
                                encoding="utf-8")["rpm"][0]
    assert data["rpm"][0] != first_plain  # the first decision was made on the feed read, not on the card's
