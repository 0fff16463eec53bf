"""A campaign on a feed that is not the card's: the advice says what it stands on before the first
sample, and a sample of the feed at 0 h moves the estimate to it (the filter's ``feed_log_std``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bmctl import campaign as cp
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"  # [initial] s_mean_um = 40
MPC = ROOT / "controllers" / "mpc-default.toml"


def test_feed_sample_at_zero_is_read_and_the_note_goes(tmp_path):
    d = tmp_path / "c"
    cp.init(d, CARD, MPC, {"s_mean_um": 45.0}, hours=3.0, particles=400)
    a = cp.advise(d)
    assert any(n.startswith("no sample yet") for n in a["notes"])
    g = np.random.default_rng(0)
    sigma = 0.3
    s_um = g.lognormal(math.log(60.0), sigma, 300)
    cp.sample(d, 0.0, [ParticleTable.from_size_aspect(s_um, g.uniform(0.0, 0.05, 300))])
    b = cp.advise(d)
    assert b["notes"] == []
    truth = 60.0 * math.exp(sigma**2 / 2)
    est = b["estimate"]
    assert est["s_mean_um_q05"] <= truth <= est["s_mean_um_q95"]
    assert est["gamma_mult_q95"] / est["gamma_mult_q05"] > 2.0  # the feed says nothing of gamma
    assert b["next"]["mill_min"] > 0  # 60 um down to 45 um: milling, not a rest at a card's 40 um
