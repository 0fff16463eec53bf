"""What an operator enters counts and what they are shown is one number per quantity:
vial readings in the estimate (and their warnings), rests, one D50, the report's content."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.cli import main
from bmctl.measure.tables import ParticleTable
from bmctl.moments import make_moment_model

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"
SIGMA_C = 2.0  # the stated noise of a reading (docs/campaign.md)


def _table(seed: int, s_um: float = 45.0, n: int = 150) -> ParticleTable:
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(s_um), 0.45, n), rng.uniform(0.0, 0.12, n))


# --- vial readings -------------------------------------------------------------------------------
def test_temperature_estimate_follows_made_up_readings_within_their_noise(tmp_path):
    """A vial that heats 1.4 times as much as the card's thermal law says (made up), read with
    N(0, 2 degC) noise: after the first reading the estimate stays within 2 sigma of the true
    vial temperature, through rpm changes and a rest (cooling to ambient), and the gain's 90 %
    interval holds 1.4. With readings ignored it would sit at the card's law, 10-17 degC low."""
    gain_true, amb = 1.4, 25.0
    model = make_moment_model(CARD)
    assert model.x0()[4] == amb
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=5.0, particles=300, seed=1)
    rng = np.random.default_rng(11)
    x = model.x0()
    schedule = [(300, 1.0), (300, 1.0), (400, 1.0), (400, 0.5), (0, 0.0), (200, 1.0), (300, 1.0), (300, 1.0)]
    errs, law_gap = [], []
    with cp.Campaign(d) as c:
        for k, (rpm, milling) in enumerate(schedule):
            x = np.asarray(model.step(x, np.array([rpm, milling], float), 0.5))
            truth = amb + gain_true * (x[4] - amb)
            reading = truth + SIGMA_C * rng.standard_normal()
            est = cp.log(d, rpm, 0.5, milling, temperature_c=round(reading, 1), campaign=c)["estimate"]
            if k:
                errs.append(est["temperature_c"] - truth)
                law_gap.append(truth - x[4])
        assert est["thermal_gain_q05"] <= gain_true <= est["thermal_gain_q95"]
    errs = np.abs(errs)
    assert errs.max() < 2 * SIGMA_C, errs
    assert max(law_gap) > 10.0  # the card's law alone would be far off: the readings carry the estimate


def _lqr_campaign(tmp_path, capsys, *more) -> str:
    """A fresh 2-h campaign folder on the lab card with the LQR baseline (s_mean 45 um, the moment it
    tracks; 100 filter particles)."""
    d = str(tmp_path / "c")
    assert main(["campaign", "init", d, "--model", str(CARD), "--controller", str(LQR), "--target", "s_mean_um=45",
                 "--hours", "2", "--particles", "100", *more]) == 0
    capsys.readouterr()
    return d


def test_reading_above_the_ceiling_or_far_off_warns_in_log_and_in_the_next_advice(tmp_path, capsys):
    d = _lqr_campaign(tmp_path, capsys, "--temperature-max-c", "60")
    # the card's law puts the vial near 60 degC after 30 min at 300 rpm, +-10 degC with the heating gain's
    # prior (+-30 %): a vial still at the room's 25 degC is far from it
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "25"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"warning: reading 25 °C at 0\.5 h is far from the estimate just before it", out)
    assert "above the ceiling" not in out
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "75"]) == 0
    out = capsys.readouterr().out
    assert "warning: reading 75 °C at 1 h is above the ceiling (60 °C)" in out
    est_line = re.search(r"temperature_c (\S+)", out.splitlines()[-1])
    assert abs(float(est_line.group(1)) - 75.0) < 3 * SIGMA_C  # the estimate follows the reading
    assert main(["campaign", "advise", d]) == 0
    out = capsys.readouterr().out
    assert "warning: reading 75 °C at 1 h is above the ceiling (60 °C)" in out
    assert "warning: reading 25 °C at 0.5 h is far from the estimate" in out  # not advised since
    assert re.search(r"warning: estimated vial temperature at 1 h: \S+ \[\S+, \S+\] °C, above the ceiling", out)
    # an in-range reading next: the next advice repeats none of the old warnings
    assert main(["campaign", "log", d, "--rpm", "0", "--hours", "0.5", "--temperature-c", "32"]) == 0  # cooled
    assert "warning" not in capsys.readouterr().out
    assert main(["campaign", "advise", d, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []


# --- rests -------------------------------------------------------------------------------------------
def test_a_rest_logs_as_a_rest_and_a_followed_advice_is_no_deviation(tmp_path, capsys):
    d = str(tmp_path / "c")
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=2.0, particles=100, temperature_max_c=60)
    cp.log(d, 300, 0.5, temperature_c=75.0)  # hot vial: the guard advises a rest
    a = cp.advise(d)
    assert a["next"]["mill_min"] == 0 and a["next"]["rest_min"] == 30
    cp.decide(d, True)
    capsys.readouterr()
    assert main(["campaign", "log", d, "--rpm", "0", "--hours", "0.5"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("logged 0.5-1 h: rest 30 min\n") and "deviation" not in out
    with cp.Campaign(d) as c:
        act = c.actions()[-1]
        assert (act.rpm, act.milling) == (0.0, 0.0)
        assert c.con.execute("SELECT deviation FROM actions WHERE id = ?", (act.id,)).fetchone()[0] == ""
    # milling 0 at a stated rpm is a rest too; milling against an advised rest is a deviation
    a = cp.advise(d)
    r = cp.log(d, 250, 0.5, milling=0.0)
    assert (r["rpm"], r["milling"]) == (0.0, 0.0)
    assert r["deviation"] == "" or a["next"]["mill_min"] > 0
    a = cp.advise(d)
    rec = a["next"]
    r = cp.log(d, 300, 0.5, milling=1.0)
    if rec["mill_min"] == 0:
        assert r["deviation"].endswith("milling 30 min (recommended 0)")
    else:
        assert ("milling" in r["deviation"]) == (rec["mill_min"] != 30)


# --- one D50, one report -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A short campaign with samples, accepted and rejected advice, a note, readings and a rest."""
    d = tmp_path_factory.mktemp("op") / "c"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=3.0, particles=200, temperature_max_c=60)
    with cp.Campaign(d) as c:
        cp.log(d, 300, 0.5, temperature_c=57.0, campaign=c)
        cp.sample(d, 0.5, [_table(1, 60.0)], campaign=c)
        a = cp.advise(d, campaign=c)
        cp.decide(d, True, note="ran as advised", campaign=c)
        cp.log(d, a["next"]["rpm"], 0.5, a["next"]["mill_min"] / 30, temperature_c=75.0, campaign=c)
        cp.advise(d, campaign=c)
        cp.decide(d, False, rpm=200, note="operator <b>cautious</b> & careful", campaign=c)
        cp.log(d, 200, 0.5, temperature_c=55.0, campaign=c)
        cp.sample(d, 1.5, [_table(2, 50.0)], campaign=c)
        cp.advise(d, campaign=c)
    return str(d)


def test_status_text_json_and_report_show_one_d50(run, capsys):
    assert main(["campaign", "status", run, "--json"]) == 0
    est = json.loads(capsys.readouterr().out)["estimate"]
    want = f"{est['d50_um']:.4g}  [{est['d50_um_q05']:.4g}, {est['d50_um_q95']:.4g}]"
    assert est["d50_um_q05"] <= est["d50_um"] <= est["d50_um_q95"]
    assert main(["campaign", "status", run]) == 0
    text = capsys.readouterr().out
    assert re.search(r"^  d50_um\s+(.*)$", text, re.M).group(1) == want
    assert main(["campaign", "report", run]) == 0
    page = (Path(run) / "report.html").read_text(encoding="utf-8")
    assert f"<td>d50_um</td><td>{want}</td>" in page  # the report's "estimate now"
    # the advice printed at the clock shows the same estimate
    assert main(["campaign", "advise", run]) == 0
    assert re.search(r"^  d50_um\s+(.*)$", capsys.readouterr().out, re.M).group(1) == want


def test_report_holds_estimates_against_samples_decisions_notes_plans_and_readings(run):
    cp.report(run)
    page = (Path(run) / "report.html").read_text(encoding="utf-8")
    with cp.Campaign(run) as c:
        n_plans = c.con.execute("SELECT COUNT(*) FROM plans").fetchone()[0]
        s, _ = c.particles(1)
    # every advice, with its decision, note, deviation and the plan that was advised
    assert n_plans >= 3
    assert page.count('<section class="advice"') == n_plans
    assert page.count('<div class="plan">') == n_plans
    assert "<dd>accepted</dd>" in page and "<dd>rejected; instead 200 rpm</dd>" in page
    assert "<dd>ran as advised</dd>" in page
    assert "operator &lt;b&gt;cautious&lt;/b&gt; &amp; careful" in page and "<b>cautious</b>" not in page
    assert "deviation from the recommendation (advice rejected)" in page
    # per sample: the estimate next to the sample's statistic of the same quantity
    for q in ("s_mean_um: sample mean", "s_std_um: sample std", "r_mean: sample mean", "d50_um: sample D50"):
        assert q in page
    from bmctl.stats import dvalues

    assert f"<td>{np.mean(s):.4g}</td>" in page and f"<td>{dvalues(s)['d50_um']:.4g}</td>" in page
    # readings against the ceiling
    assert "reading 75 °C at 1 h is above the ceiling (60 °C)" in page
    assert "<td>75</td><td>ABOVE</td>" in page
    assert page.count("data:image/png;base64,") == 4


def test_a_far_reading_of_a_rested_vial_names_the_cards_room_temperature(tmp_path, capsys):
    d = _lqr_campaign(tmp_path, capsys)
    # a rested vial is at the card's ambient (25 degC) for sure: a 15 degC reading is the room, not the heating
    assert main(["campaign", "log", d, "--rpm", "0", "--hours", "0.5", "--temperature-c", "15"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"reading 15 °C at 0\.5 h is far from the estimate .*set thermal\.ambient_C in the card", out)
    # a milling vial's far reading is the heating, which the filter learns: no such hint
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "120"]) == 0
    out = capsys.readouterr().out
    assert "reading 120 °C at 1 h is far from the estimate" in out and "ambient_C" not in out


def test_a_far_first_reading_of_a_milling_vial_does_not_name_the_room_temperature(tmp_path, capsys):
    """Before the first reading every filter particle heats as the card says; the reading's predicted
    spread is the heating gain's prior (+-30 % of the heating: +-10.6 degC after 30 min at 300 rpm). A
    reading far outside it (100 degC for 60) is the heating, which the filter learns, not the card's
    ambient_C; 80 degC, within the prior, is not far."""
    d = _lqr_campaign(tmp_path, capsys)
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "100"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"reading 100 °C at 0\.5 h is far from the estimate just before it \(60\.\d ± 10\.\d °C", out)
    assert "ambient_C" not in out and "room" not in out
    # the report and status repeat the warning without the hint
    assert main(["campaign", "status", d]) == 0
    assert "ambient_C" not in capsys.readouterr().out
    d2 = _lqr_campaign(tmp_path / "2", capsys)
    assert main(["campaign", "log", d2, "--rpm", "300", "--hours", "0.5", "--temperature-c", "80"]) == 0
    assert "far from" not in capsys.readouterr().out
