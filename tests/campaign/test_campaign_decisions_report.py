"""What a campaign records and reports agree: a decision on an advice repeated at the same time still
stands, the report shows the prior before anything is logged, a table ``bmctl measure`` wrote keeps
its particles' images and centroids, ``trial --campaign`` tallies the binding limits a plain trial
does, and the LQR's temperature guard names the minutes it applies."""

from __future__ import annotations

import html
import json
import re
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.tables import ParticleLocations, ParticleTable, write_table

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
MPC = ROOT / "controllers" / "mpc-default.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"


def _table(seed: int, s_um: float = 45.0, n: int = 60) -> ParticleTable:
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(s_um), 0.45, n), rng.uniform(0.0, 0.12, n))


def _advices(page: str) -> dict[int, dict[str, str]]:
    """The report's advice sections: {advice id: {term: text}}."""
    out = {}
    for pid, dl in re.findall(r'<section class="advice" id="advice-(\d+)">.*?<dl>(.*?)</dl>', page, re.S):
        out[int(pid)] = {html.unescape(k): html.unescape(v)
                         for k, v in re.findall(r"<dt>(.*?)</dt><dd>(.*?)</dd>", dl, re.S)}
    return out


# --- a decision before the advice is asked for again at the same time --------------------------
def test_a_decision_stands_when_the_advice_is_repeated_at_the_same_time(tmp_path, capsys):
    """decide, then advise again at the same logged time (the same advice): status, log's deviation
    and the report read the decision, not "no decision"."""
    d = str(tmp_path / "c")
    assert main(["campaign", "init", d, "--model", str(CARD), "--controller", str(MPC), "--target", "d50_um=45",
                 "--particles", "100", "--hours", "2"]) == 0
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5"]) == 0
    capsys.readouterr()
    assert main(["campaign", "advise", d, "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert main(["campaign", "decide", d, "--reject", "--rpm", "200", "--note", "operator chose 200"]) == 0
    capsys.readouterr()
    assert main(["campaign", "advise", d, "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["plan_id"] == first["plan_id"] + 1 and again["next"] == first["next"]  # the advice repeated
    assert first["next"]["rpm"] != 200
    st = cp.status(d)
    assert st["decision"] == {"accepted": False, "rpm": 200.0, "milling": None, "advice_id": first["plan_id"]}
    assert main(["campaign", "status", d]) == 0
    out = capsys.readouterr().out
    assert re.search(r"latest advice at 0\.5 h: .*; rejected$", out, re.M), out
    assert "no decision" not in out
    assert main(["campaign", "log", d, "--rpm", "200", "--hours", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "deviation from the recommendation (advice rejected): rpm 200" in out, out
    assert "no decision recorded" not in out
    page = cp.report(d).read_text(encoding="utf-8")
    adv = _advices(page)
    a1, a2 = adv[first["plan_id"]], adv[again["plan_id"]]
    assert a1["decision"] == "rejected; instead 200 rpm" and a1["note"] == "operator chose 200"
    assert a1["then logged"] == f"nothing under this advice: advice {again['plan_id']} at this time repeats it"
    assert a2["decision"] == (f"rejected; instead 200 rpm (recorded on advice {first['plan_id']}, "
                              "which this advice repeats)")
    assert a2["note"] == "operator chose 200" and a2["then logged"].startswith("0.5-1 h: 200 rpm")
    assert "(advice rejected)" in a2["deviation"]
    assert "no decision recorded" not in page


def test_a_decision_does_not_stand_for_an_advice_that_differs(tmp_path):
    """A sample at the logged time between the decision and the next advice changes the advice: the
    decision on the earlier one does not stand for it."""
    d = tmp_path / "c"
    cp.init(d, CARD, MPC, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, rpm=300.0, hours=0.5)
    a1 = cp.advise(d)
    cp.decide(d, True)
    assert cp.status(d)["decision"]["advice_id"] == a1["plan_id"]
    cp.sample(d, 0.5, [_table(3, s_um=20.0)])  # far finer than the estimate: the advice changes
    a2 = cp.advise(d)
    assert a2["next"] != a1["next"]
    assert cp.status(d)["decision"] is None
    adv = _advices(cp.report(d).read_text(encoding="utf-8"))
    assert adv[a1["plan_id"]]["decision"] == "accepted"
    assert adv[a1["plan_id"]]["then logged"] == (f"nothing under this advice: advice {a2['plan_id']} at this time "
                                                "replaces it")
    assert adv[a2["plan_id"]]["decision"] == "no decision recorded"
    cp.decide(d, True)  # its own decision
    dec = cp.status(d)["decision"]
    assert dec["accepted"] and dec["advice_id"] == a2["plan_id"]


# --- the report before anything is logged ------------------------------------------------------
def test_report_of_a_fresh_campaign_shows_the_prior_labelled(tmp_path):
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    est = cp.status(d)["estimate"]
    assert est["t_h"] < 0  # the prior, as `status` prints it ("estimate (prior):")
    now = cp.report(d).read_text(encoding="utf-8").split("<h2>Estimate now</h2>")[1].split("<h2>")[0]
    assert "prior" in html.unescape(now)
    shown = re.findall(r"<td>([a-z_0-9]+)</td>", now)
    assert {"s_mean_um", "d50_um", "temperature_c"} <= set(shown)
    assert f"{est['d50_um']:.4g}" in now
    cp.log(d, rpm=300.0, hours=0.5)
    now = cp.report(d).read_text(encoding="utf-8").split("<h2>Estimate now</h2>")[1].split("<h2>")[0]
    assert "prior" not in now and "at 0.5 h" in now
    assert f"{cp.status(d)['estimate']['d50_um']:.4g}" in now


# --- a table written by `bmctl measure` ----------------------------------------------------------
def test_sample_of_a_measured_table_keeps_images_and_centroids(tmp_path):
    """`bmctl measure` writes particle_id,image,x_um,y_um before the particle columns: the sample stores
    each particle's image and centroid (docs/campaign.md), and the same particles entered again
    are still refused."""
    t = _table(1, n=6)
    x = np.array([10.5, 20.25, np.nan, 40.0, 50.0, 60.0])
    loc = ParticleLocations(np.arange(1, 7), ("a.tif",) * 3 + ("b.tif",) * 3, x, x + 1.0)
    csv = tmp_path / "m.csv"
    write_table(csv, t, loc)
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, rpm=300.0, hours=0.5)
    sid = cp.sample(d, 0.5, [csv])["sample_id"]
    con = sqlite3.connect(str(Path(d) / db.DB_NAME))
    rows = con.execute("SELECT image, x_um, y_um FROM particles WHERE sample_id = ? ORDER BY particle_id",
                       (sid,)).fetchall()
    con.close()
    assert [r[0] for r in rows] == ["a.tif"] * 3 + ["b.tif"] * 3
    assert rows[0][1:] == (10.5, 11.5) and rows[1][1:] == (20.25, 21.25)
    assert rows[2][1:] == (None, None) and rows[5][1:] == (60.0, 61.0)  # an empty centroid is NULL
    # a table of the particle columns only: the table's own path, no centroid (a table in memory: "(table)")
    plain = tmp_path / "plain.csv"
    write_table(plain, _table(5, n=5))
    sid = cp.sample(d, 0.5, [plain, _table(2, n=4)])["sample_id"]
    con = sqlite3.connect(str(Path(d) / db.DB_NAME))
    rows = con.execute("SELECT image, x_um, y_um FROM particles WHERE sample_id = ? ORDER BY particle_id",
                       (sid,)).fetchall()
    con.close()
    assert rows == [(str(plain), None, None)] * 5 + [("(table)", None, None)] * 4
    # the same particles again, in other bytes (a comment line): refused as before
    again = tmp_path / "again.csv"
    again.write_text("# measured again\n" + csv.read_text(encoding="utf-8"), encoding="utf-8")
    with pytest.raises(InputError, match=r"the same particles as"):
        cp.sample(d, 0.5, [again])


# --- trial --campaign: the binding limits of the plans --------------------------------------------
def test_trial_campaign_reports_the_binding_limits_of_a_plain_trial(tmp_path, capsys):
    sc = tmp_path / "small.toml"
    sc.write_text(f'model = "{CARD.as_posix()}"\nhours = 1.5\ntarget = {{ d50_um = 60.0 }}\n\n'
                  '[scenario]\nname = "small"\ndescription = "binding limits of a campaign trial"\n\n'
                  "[plant]\nparticles = 500\ngamma_factor = 1.2\n\n[sampling]\nparticles = 100\n\n"
                  f'[estimator]\nparticles = 100\n\n[controller]\nconfig = "{MPC.as_posix()}"\n', encoding="utf-8")
    plain, camp = tmp_path / "plain", tmp_path / "camp"
    assert main(["trial", str(sc), "--seed", "1", "--out", str(plain), "--no-progress"]) == 0
    out_plain = capsys.readouterr().out
    assert main(["trial", str(sc), "--seed", "1", "--out", str(camp), "--no-progress", "--campaign"]) == 0
    out_camp = capsys.readouterr().out
    s1 = json.loads((plain / "summary.json").read_text(encoding="utf-8"))
    s2 = json.loads((camp / "summary.json").read_text(encoding="utf-8"))
    assert s1["binding_first"], "the scenario's first plan names its binding limits"
    assert s2["binding_first"] == s1["binding_first"] and s2["binding_last"] == s1["binding_last"]
    line = [ln for ln in out_plain.splitlines() if "binding limits of the first plan" in ln]
    assert line and line == [ln for ln in out_camp.splitlines() if "binding limits of the first plan" in ln]
    h1, *a = (plain / "trajectory.csv").read_text(encoding="utf-8").splitlines()
    h2, *b = (camp / "trajectory.csv").read_text(encoding="utf-8").splitlines()
    keep = [i for i, k in enumerate(h1.split(",")) if k != "solve_ms"]  # wall time differs run to run
    assert h1 == h2 and [[r.split(",")[i] for i in keep] for r in a] == [[r.split(",")[i] for i in keep] for r in b]


# --- the LQR's temperature guard -------------------------------------------------------------------
def test_lqr_temperature_guard_names_the_minutes_applied(tmp_path):
    """The guard's note once named the unrounded share (1.00 -> 0.36) while 10 whole minutes were
    applied: it names the minutes the advice runs."""
    d = tmp_path / "c"
    cp.init(d, CARD, LQR, {"s_mean_um": 45.0}, hours=2.0, particles=100, temperature_max_c=60.0)
    cp.log(d, rpm=300.0, hours=0.5, temperature_c=40.0)
    a = cp.advise(d)
    m = re.search(r"temperature guard: milling (\d+) -> (\d+) min(;|\))", a["solver"])
    assert m, a["solver"]
    assert "dwell" not in a["solver"]  # nothing else changed the minutes after the guard
    assert int(m.group(2)) == a["next"]["mill_min"] > 0 and int(m.group(1)) == 30
