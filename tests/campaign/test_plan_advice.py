"""Advice from a plan on operable schedules (controllers/mpc-default.toml, ``[plan] method = "search"``):
the same database gives the same advice, the advice is the plan's first interval, ``binding`` names
only limits the plan meets, and the logged history plus the plan keep the mill's limits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.control.config import load_controller
from bmctl.control.mill import check_schedule
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
MPC = ROOT / "controllers" / "mpc-default.toml"


def _sample(rng, mean_um):
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(mean_um), 0.45, 200), rng.uniform(0, 0.1, 200))


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("plan") / "c"
    cp.init(d, CARD, MPC, {"s_mean_um": 36.0}, hours=3.0, particles=200)
    rng = np.random.default_rng(0)
    with cp.Campaign(d) as c:
        cp.log(d, 300, 0.5, 1.0, temperature_c=60.0, campaign=c)
        cp.log(d, 300, 0.5, 0.1, temperature_c=45.0, campaign=c)  # 3 min, then a rest: off the advice
        cp.sample(d, 1.0, [_sample(rng, 45.0)], campaign=c)
    return d


def test_same_database_same_advice(campaign):
    a = cp.advise(campaign)
    b = cp.advise(campaign)  # a second advice at the same logged time starts from the same state
    for k in ("next", "schedule", "binding", "reachable", "end"):
        assert a[k] == b[k], k


def test_advice_is_the_plans_first_interval_and_binding_agrees(campaign):
    a = cp.advise(campaign)
    first = a["schedule"][0]
    assert (a["next"]["rpm"], a["next"]["mill_min"], a["next"]["rest_min"]) == \
        (first["rpm"], first["mill_min"], first["rest_min"])
    assert all(r["planned"] for r in a["schedule"])  # the plan reaches the batch end
    cfg = load_controller(MPC)
    top = min(cfg.bounds.rpm_max, 600.0)
    at_top = any(r["mill_min"] > 0 and r["rpm"] >= top - 1e-6 for r in a["schedule"])
    assert at_top == any("upper bound" in b for b in a["binding"])


def test_logged_history_and_plan_keep_the_mills_limits(campaign):
    """The operator milled 3 min (under the 5 min minimum) after a full interval, so that period
    merged into 33 min; the plan continues from there and keeps every limit to the batch end."""
    a = cp.advise(campaign)
    mill = load_controller(MPC).mill
    segs = [(0.5, 300.0), (0.05, 300.0), (0.45, 0.0)]
    for r in a["schedule"]:
        h = r["t1_h"] - r["t0_h"]
        segs += [(r["mill_min"] / 60.0, r["rpm"]), (h - r["mill_min"] / 60.0, 0.0)]
    assert check_schedule([(h, r) for h, r in segs if h > 1e-12], mill) == []


def test_advice_says_how_closely_the_last_sample_reads_the_mean_size(campaign, capsys):
    """``sampling``: the relative standard error of the last sample's mean (sd / mean / sqrt(n), from its
    particle table) and the count that reads it within the controller's tolerance at 95 %."""
    from bmctl.commands.campaign import _print_advice

    a = cp.advise(campaign)
    with cp.Campaign(campaign) as c:
        sid = c.con.execute("SELECT id FROM samples ORDER BY t_h DESC LIMIT 1").fetchone()[0]
        s_um = np.array([r[0] for r in c.con.execute("SELECT s_um FROM particles WHERE sample_id = ?", (sid,))])
    tol = load_controller(MPC).objective.tolerance
    cv = s_um.std(ddof=1) / s_um.mean()
    sm = a["sampling"]
    assert sm["t_h"] == 1.0 and sm["particles"] == s_um.size == 200
    assert sm["mean_se_pct"] == pytest.approx(100 * cv / np.sqrt(200))
    n_tol = sm["particles_for_tolerance"]
    assert 1.96 * cv / np.sqrt(n_tol) <= tol < 1.96 * cv / np.sqrt(n_tol - 1)
    _print_advice(a)
    assert f"about {n_tol} particles would read it within the 2 % tolerance" in capsys.readouterr().out


def _near_target(tmp_path, median_um):
    """A 3-h campaign to 36 µm, milled 1 h at 300 rpm, with one 200-particle sample at 1 h."""
    d = tmp_path / f"near-{median_um:g}"
    cp.init(d, CARD, MPC, {"s_mean_um": 36.0}, hours=3.0, particles=200)
    rng = np.random.default_rng(0)
    with cp.Campaign(d) as c:
        cp.log(d, 300, 0.5, 1.0, temperature_c=60.0, campaign=c)
        cp.log(d, 300, 0.5, 1.0, temperature_c=65.0, campaign=c)
        cp.sample(d, 1.0, [_sample(rng, median_um)], campaign=c)
    return d, rng


def test_a_correction_the_estimate_cannot_resolve_asks_for_one_more_sample(tmp_path, capsys):
    """A milling move while the target lies inside the estimate's 90 % interval asks for another sample
    at the same batch time; with two samples there the advice asks no more (and acts)."""
    from bmctl.commands.campaign import _print_advice

    d, rng = _near_target(tmp_path, 34.0)
    a = cp.advise(d)
    e = a["estimate"]
    assert a["next"]["mill_min"] > 0 and e["s_mean_um_q05"] <= 36.0 <= e["s_mean_um_q95"]
    assert abs(e["s_mean_um"] - 36.0) > 0.02 * 36.0
    assert a["sample_first"].endswith("another sample before milling")
    assert cp.advise(d)["sample_first"] == a["sample_first"]  # the same database, the same request
    _print_advice(a)
    assert "sample first: s_mean_um" in capsys.readouterr().out
    cp.sample(d, 1.0, [_sample(rng, 34.0)])
    assert cp.advise(d)["sample_first"] is None
    cp.report(d)
    page = (d / "report.html").read_text(encoding="utf-8")
    assert page.count("<dt>sample first</dt><dd>s_mean_um") == 2 and "<dd>not asked</dd>" in page


def test_stopping_on_an_estimate_the_interval_does_not_resolve_asks_for_one_more_sample(tmp_path):
    d, _ = _near_target(tmp_path, 33.0)
    a = cp.advise(d)
    assert a["next"]["mill_min"] == 0 and abs(a["estimate"]["s_mean_um"] - 36.0) <= 0.02 * 36.0
    assert a["sample_first"].endswith("another sample before stopping")


def test_no_sample_is_asked_for_before_the_first_or_when_the_interval_excludes_the_target():
    from bmctl.campaign.advice import sample_first

    est = {"s_mean_um": 37.2, "s_mean_um_q05": 35.7, "s_mean_um_q95": 38.9}
    assert sample_first(est, {"s_mean_um": 36.0}, 0.02, 5, True, 1, 1) is not None
    assert sample_first(est, {"s_mean_um": 36.0}, 0.02, 5, True, 0, 0) is None  # only the card's prior
    assert sample_first(est, {"s_mean_um": 35.0}, 0.02, 5, True, 1, 1) is None  # outside the interval
    assert sample_first(est, {"s_mean_um": 36.0}, 0.02, 0, True, 1, 1) is None  # a rest 3 % off: not a stop
    assert sample_first({**est, "s_mean_um": 36.3}, {"s_mean_um": 36.0}, 0.02, 0, False, 1, 1) is None  # resting on


def test_binding_reads_the_schedule_the_mill_runs_not_the_unrounded_plan():
    """An NLP plan's small milling shares at the top speed that whole minutes round to rests bind
    nothing: "rpm at its upper bound" is named only when a shown row mills there."""
    from types import SimpleNamespace

    from bmctl.campaign.advice import _why

    cfg = load_controller(ROOT / "controllers" / "mpc-nominal.toml")
    c = SimpleNamespace(meta={"target": {"s_mean_um": 36.0}},
                        loop=SimpleNamespace(controller=SimpleNamespace(cfg=cfg), model=SimpleNamespace(rpm_max=600.0)))
    plan = SimpleNamespace(extra={}, u=np.array([[500.0, 0.01]] * 4), t_peak_c=np.full(4, 30.0),
                           status=SimpleNamespace(t_ceiling_c=80.0))
    end = {"s_mean_um": {"median": 40.0, "q05": 39.0, "q95": 41.0}}

    def rows(mill_min):
        return [{"t0_h": 0.5 * k, "t1_h": 0.5 * k + 0.5, "rpm": 500.0 if mill_min else 0.0, "milling": mill_min / 30.0,
                 "mill_min": mill_min, "rest_min": 30 - mill_min, "planned": True} for k in range(4)]

    _, resting = _why(c, plan, rows(0), end, None)
    assert not any("upper bound" in b for b in resting)
    assert resting == ["batch time: the target is not reached by the batch end at the planned inputs"]
    _, milling = _why(c, plan, rows(12), end, None)
    assert any("upper bound" in b for b in milling)
