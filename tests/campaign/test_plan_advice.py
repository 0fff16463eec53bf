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
