"""What ``advise`` says about its footing and its limits: the note before the first sample after
logged milling, ``binding`` when the mill's dwell limits rounded the advice, and ``next`` of a
batch that ends inside a control interval (its milling a share of the interval it shows)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"  # [initial] s_mean_um = 40
LQR = ROOT / "controllers" / "lqr-baseline.toml"  # 0.5 h intervals, [mill] min_mill_min = 5


@pytest.fixture(scope="module")
def milled(tmp_path_factory):
    """2 h logged at 300 rpm, no sample, 3 min of the 2.05 h batch left: the advice there."""
    d = tmp_path_factory.mktemp("milled") / "D"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=2.05, particles=200)
    for _ in range(4):
        cp.log(d, 300.0, 0.5)
    return cp.advise(d)


def test_the_note_before_a_sample_says_the_card_s_powder_was_carried_forward(milled):
    note = next(n for n in milled["notes"] if n.startswith("no sample yet"))
    # the card's starting powder is 40 um; the estimate after 2 h of milling is the model's, not it
    assert "starting powder (s_mean_um 40)" in note and "carried forward by the model over the 2 h logged" in note
    assert f"s_mean_um {milled['estimate']['s_mean_um']:.4g} now" in note
    assert "--at-h 2 " in note and "advise again" in note  # still advises a sample


def test_binding_names_the_dwell_rule_that_rounded_the_advice_to_a_rest(milled):
    assert "dwell limits: milling 3 -> 0 min" in milled["solver"]
    assert milled["next"]["mill_min"] == 0
    assert any(b.startswith("minimum milling period (5 min) now") for b in milled["binding"]), milled["binding"]


def test_next_of_a_short_last_interval_is_a_share_of_the_interval_it_shows(tmp_path):
    d = tmp_path / "E"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=0.3, particles=200)
    a = cp.advise(d)
    nx = a["next"]
    assert nx["interval_h"] == pytest.approx(0.3) and nx["mill_min"] == 18
    assert nx["milling"] * nx["interval_h"] * 60.0 == pytest.approx(nx["mill_min"])
    assert nx["milling"] == pytest.approx(a["schedule"][0]["milling"])
    la = cp.status(d)["latest_advice"]
    assert la["milling"] * la["interval_h"] * 60.0 == pytest.approx(la["mill_min"])
    # what is stored and decided stays the controller's share of its 0.5 h interval (18 of 30 min)
    con = sqlite3.connect(str(d / db.DB_NAME))
    stored, stored_h, doc = con.execute("SELECT milling, interval_h, advice FROM plans").fetchone()
    con.close()
    assert (stored, stored_h) == (pytest.approx(0.6), pytest.approx(0.5))
    assert json.loads(doc)["next"]["milling"] == pytest.approx(1.0)
    assert cp.decide(d, True)["recommended_milling"] == pytest.approx(0.6)


def test_decide_prints_the_recommended_minutes_of_a_short_last_interval(tmp_path, capsys):
    from bmctl.cli import main

    d = tmp_path / "F"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=0.3, particles=200)
    cp.advise(d)
    assert main(["campaign", "decide", str(d), "--accept"]) == 0
    out = capsys.readouterr().out
    assert "milling 0.6: 18 of 18 min)" in out  # the share is of 30 min; the mill runs all of the last 18


def test_a_sample_waiting_for_the_log_leaves_the_note_before_a_sample(tmp_path):
    """A sample entered ahead of the log (at 2 h, the log at 1 h) is not in the estimate yet: the
    advice still stands on the card's powder carried forward, and says so rather than calling the
    estimate uncertain because samples disagree with the model."""
    from bmctl.measure.tables import ParticleTable
    import numpy as np

    d = tmp_path / "P"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=3.0, particles=200)
    cp.log(d, 300.0, 1.0)
    rng = np.random.default_rng(0)
    cp.sample(d, 2.0, [ParticleTable.from_size_aspect(rng.lognormal(np.log(45.0), 0.45, 100),
                                                      rng.uniform(0.0, 0.12, 100))])
    a = cp.advise(d)
    assert a["pending_samples"] == 1
    assert any(n.startswith("no sample yet") and "carried forward by the model over the 1 h logged" in n
               for n in a["notes"]), a["notes"]
    assert not any("samples disagree" in n for n in a["notes"]), a["notes"]
