"""bmctl campaign: SQLite log, estimator timeline, CLI, crash safety, report in a browser, trial equivalence."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import db, targets as tg
from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"


def _table(seed: int, s_um: float = 45.0, n: int = 150) -> ParticleTable:
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(s_um), 0.45, n), rng.uniform(0.0, 0.12, n))


def _init(d, ctrl=RECIPE, **kw):
    """A 2-h campaign on the lab card: D50 45 µm (the LQR, which tracks the mean size: s_mean 45 µm)."""
    kw.setdefault("hours", 2.0)
    kw.setdefault("particles", 100)
    return cp.init(d, CARD, ctrl, {"s_mean_um" if ctrl == LQR else "d50_um": 45.0}, **kw)


def _states(d) -> list[tuple[float, bytes]]:
    con = sqlite3.connect(str(Path(d) / db.DB_NAME))
    out = con.execute("SELECT t_h, state FROM estimator_states ORDER BY t_h").fetchall()
    con.close()
    return out


# --- targets -----------------------------------------------------------------------------------
def test_controller_takes_a_d50_target_as_it_is():
    """The controller's objective reads D50 from the size law: the campaign passes the target through."""
    assert tg.controller_target({"d50_um": 45.0}, {"s_mean_um": 60.0, "s_std_um": 30.0}) == {"d50_um": 45.0}


def test_target_parse_errors():
    assert tg.parse("d50_um=45,r_mean=0.05") == {"d50_um": 45.0, "r_mean": 0.05}
    for bad in ("d10_um=3", "d50_um=-1", "d50_um", "d50_um=45,s_mean_um=40", ""):
        with pytest.raises(InputError):
            tg.parse(bad)
    with pytest.raises(InputError, match="not a window .e.g. d50_um=65."):  # design's window form, named
        tg.parse("d50_um=60:70")
    with pytest.raises(InputError, match="must be in"):  # below a nanometre: no particle is that small
        tg.parse("s_mean_um=1e-320")
    with pytest.raises(InputError, match="D90 <= D50"):
        tg.parse("d50_um=45,d90_um=40")
    with pytest.raises(InputError, match=r"unknown target 's_maen_um' \(did you mean s_mean_um\?\)"):
        tg.parse("s_maen_um=40")
    from bmctl.control.config import parse_target

    assert parse_target("d50_um=45,d90_um=40:60") == {"d50_um": 45.0, "d90_um": (40.0, 60.0)}  # D90 in (45, 60] meets it


# --- the log -----------------------------------------------------------------------------------
def test_state_blob_round_trip_without_pickle():
    state = {"X": np.arange(6.0).reshape(2, 3), "rng": {"state": {"state": 2**100}}, "k": [1, None, "a"]}
    back = db.unpack(db.pack(state))
    assert back["X"].tolist() == state["X"].tolist() and back["rng"]["state"]["state"] == 2**100
    with pytest.raises(InputError):
        db.unpack(b"garbage")


def test_log_refuses_overlap_gap_and_end(tmp_path):
    d = tmp_path / "c"
    _init(d)
    cp.log(d, 300, 0.5)
    with pytest.raises(InputError, match="backwards"):
        cp.log(d, 300, 0.5, from_h=0.25)
    with pytest.raises(InputError, match="gap"):
        cp.log(d, 300, 0.5, from_h=1.0)
    with pytest.raises(InputError, match="batch end"):
        cp.log(d, 300, 2.0)
    with pytest.raises(InputError, match="already holds"):
        _init(d)
    assert cp.status(d)["counts"]["actions"] == 1  # refused logs left nothing behind


@pytest.mark.slow
def test_late_and_early_samples_equal_on_time(tmp_path):
    """The estimator depends on what was logged and measured, not on the order it was entered."""
    def on_time(d):
        _init(d)
        cp.log(d, 300, 0.5, temperature_c=40.0)
        cp.sample(d, 0.5, [_table(1)])
        cp.log(d, 300, 0.25, milling=0.6)
        cp.log(d, 250, 0.5)
        cp.sample(d, 1.25, [_table(2)])

    def out_of_order(d):
        _init(d)
        cp.sample(d, 1.25, [_table(2)])  # before the log reaches it: held
        cp.log(d, 300, 0.5, temperature_c=40.0)
        cp.log(d, 300, 0.25, milling=0.6)
        cp.sample(d, 0.5, [_table(1)])  # late: replayed from the node before 0.5 h
        cp.log(d, 250, 0.5)

    on_time(tmp_path / "a")
    out_of_order(tmp_path / "b")
    a, b = _states(tmp_path / "a"), _states(tmp_path / "b")
    assert [t for t, _ in a] == [t for t, _ in b] == [-1.0, 0.5, 0.75, 1.25]
    assert a[-1][1] == b[-1][1]
    # a sample inside a logged interval cuts it (mill-then-rest order kept)
    d = tmp_path / "c"
    _init(d)
    cp.log(d, 300, 1.0, milling=0.5)
    r = cp.sample(d, 0.25, [_table(3)])
    assert r["applied"] and [t for t, _ in _states(d)] == [-1.0, 0.25, 1.0]


@pytest.mark.slow
@pytest.mark.slow
def test_fresh_process_continues_exactly(tmp_path):
    """A campaign continued by new Campaign objects (new processes) equals one kept open."""
    d1, d2 = tmp_path / "one", tmp_path / "many"
    _init(d1, ctrl=LQR)
    _init(d2, ctrl=LQR)
    with cp.Campaign(d1) as c:
        for k in range(3):
            a1 = cp.advise(d1, campaign=c)
            cp.log(d1, a1["next"]["rpm"], 0.5, a1["next"]["mill_min"] / 30.0, campaign=c)
            cp.sample(d1, (k + 1) * 0.5, [_table(k)], campaign=c)
    recs = []
    for k in range(3):
        a2 = cp.advise(d2)
        recs.append(a2["next"])
        cp.log(d2, a2["next"]["rpm"], 0.5, a2["next"]["mill_min"] / 30.0)
        cp.sample(d2, (k + 1) * 0.5, [_table(k)])
    assert _states(d1)[-1][1] == _states(d2)[-1][1]
    assert cp.advise(d1)["next"] == cp.advise(d2)["next"]


def test_second_writer_is_refused_cleanly(tmp_path, monkeypatch):
    d = tmp_path / "c"
    _init(d)
    monkeypatch.setattr(db, "LOCK_TIMEOUT_S", 0.2)
    holder = sqlite3.connect(str(d / db.DB_NAME), isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    try:
        with pytest.raises(InputError, match="busy"):
            cp.log(d, 300, 0.5)
        assert cp.status(d)["clock_h"] == 0.0  # readers are not blocked (WAL)
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    cp.log(d, 300, 0.5)


@pytest.mark.slow
def test_cli_verbs_and_one_line_errors(tmp_path, capsys):
    d = str(tmp_path / "c")
    assert main(["campaign", "init", d, "--model", str(CARD), "--controller", str(RECIPE), "--target", "d50_um=45",
                 "--hours", "2", "--particles", "100", "--temperature-max-c", "60"]) == 0
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--temperature-c", "41"]) == 0
    csv = tmp_path / "s.csv"
    t = _table(5)
    csv.write_text("s_um,r\n" + "".join(f"{float(s)!r},{float(r)!r}\n" for s, r in zip(t.s_um, t.r)), encoding="utf-8")
    assert main(["campaign", "sample", d, "--at-h", "0.5", str(csv)]) == 0
    assert main(["campaign", "advise", d]) == 0
    out = capsys.readouterr().out
    assert "next: 300 rpm, mill 30 min, rest 0 min" in out and "predicted at the batch end" in out
    assert main(["campaign", "decide", d, "--reject", "--rpm", "250"]) == 0
    assert main(["campaign", "log", d, "--rpm", "250", "--hours", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "deviation from the recommendation (advice rejected): rpm 250 (recommended 300)" in out
    assert main(["campaign", "status", d]) == 0
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--from-h", "0.2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "time going backwards" in err
    assert main(["campaign", "decide", d, "--accept"]) == 2  # no advice for the logged time
    assert main(["campaign", "advise", str(tmp_path / "nothing")]) == 2


def test_log_prints_seconds_of_milling_not_a_rest(tmp_path, capsys):
    """A share of a minute of milling is stored as milling and printed so ("rest 30 min" before)."""
    d = str(tmp_path / "c")
    _init(d)
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--milling", "0.004"]) == 0
    assert main(["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--milling", "0.995"]) == 0
    out = capsys.readouterr().out
    assert "logged 0-0.5 h: 300 rpm, mill 0.12 min, rest 29.9 min" in out
    assert "logged 0.5-1 h: 300 rpm, mill 29.9 min, rest 0.15 min" in out


# --- crash safety --------------------------------------------------------------------------------
SCRIPT = r"""
import os, sys, json
import numpy as np
sys.path.insert(0, {root!r})
from bmctl import campaign as cp
from bmctl.campaign import workflow as wf
from bmctl.measure.tables import ParticleTable
d, step, crash = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "crash"
def table(seed):
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(45.0), 0.45, 150), rng.uniform(0.0, 0.12, 150))
if crash:
    orig = wf._insert_particles
    def boom(con, rows):
        orig(con, rows)
        os._exit(3)  # killed between the particle insert and the commit
    wf._insert_particles = boom
kind, arg = {plan!r}[step]
if kind == "init":
    cp.init(d, {card!r}, {ctrl!r}, {{"s_mean_um": 45.0}}, hours=2.0, particles=100)
elif kind == "advise":
    print(json.dumps(cp.advise(d)["next"]))
elif kind == "decide":
    cp.decide(d, True)
elif kind == "log":
    a = cp.status(d)["latest_advice"]
    cp.log(d, a["rpm"], 0.5, a["milling"], temperature_c=40.0 + step)
elif kind == "sample":
    inputs = [table(step)] if arg is None else [arg]
    cp.sample(d, cp.status(d)["clock_h"], inputs, um_per_px=None if arg is None else 1.0)
"""


def _image(path: Path) -> Path:
    from bmctl.io import pyplot  # noqa: F401  (matplotlib on Agg)
    from bmctl.measure.render import render_micrograph
    import matplotlib.image

    m = render_micrograph(np.random.default_rng(7), n=30, shape=(400, 400), s_px=(25.0, 60.0), um_per_px=1.0)
    matplotlib.image.imsave(path, m.image, cmap="gray", vmin=0, vmax=1)
    return path


@pytest.mark.slow
def test_crash_mid_sample_leaves_a_consistent_campaign(tmp_path):
    img = _image(tmp_path / "micrograph.png")
    plan = [("init", None)]
    for k in range(3):
        plan += [("advise", None), ("decide", None), ("log", None), ("sample", str(img) if k == 1 else None)]
    plan.append(("advise", None))
    script = tmp_path / "step.py"
    script.write_text(SCRIPT.format(root=str(ROOT), plan=plan, card=str(CARD), ctrl=str(LQR)), encoding="utf-8")
    env = dict(os.environ, MPLBACKEND="Agg")

    def run(d, step, crash=False):
        return subprocess.run([sys.executable, str(script), str(d), str(step), "crash" if crash else "ok"],
                              capture_output=True, text=True, env=env, timeout=600)

    recs = {}
    for name in ("clean", "crashed"):
        d = tmp_path / name
        recs[name] = []
        for step, (kind, _) in enumerate(plan):
            if name == "crashed" and kind == "sample" and step == 8:  # the image sample
                r = run(d, step, crash=True)
                assert r.returncode == 3, r.stderr
                con = sqlite3.connect(str(d / db.DB_NAME))
                assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
                assert con.execute("SELECT COUNT(*) FROM samples WHERE t_h = 1.0").fetchone()[0] == 0
                assert con.execute("SELECT COUNT(*) FROM particles WHERE sample_id NOT IN "
                                   "(SELECT id FROM samples)").fetchone()[0] == 0
                con.close()
            r = run(d, step)
            assert r.returncode == 0, r.stderr
            if kind == "advise":
                recs[name].append(json.loads(r.stdout.strip().splitlines()[-1]))
    assert recs["clean"] == recs["crashed"]
    assert _states(tmp_path / "clean")[-1][1] == _states(tmp_path / "crashed")[-1][1]
    assert cp.report(tmp_path / "crashed").stat().st_size > 10_000


# --- report in a real browser ----------------------------------------------------------------------
def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


@pytest.mark.slow
@pytest.mark.skipif(_chromium() is None, reason="no chromium binary on this machine (Debian: apt-get install chromium)")
def test_report_loads_in_headless_chromium(tmp_path):
    d = tmp_path / "c"
    _init(d)
    cp.log(d, 300, 0.5, temperature_c=41.0)
    cp.sample(d, 0.5, [_table(1)])
    cp.advise(d)
    cp.decide(d, True)
    cp.log(d, 300, 0.5, temperature_c=47.0)
    cp.sample(d, 1.0, [_table(2, 40.0)])
    page = cp.report(d)
    text = page.read_text(encoding="utf-8")
    assert text.count("data:image/png;base64,") == 4 and "http" not in text.replace("http-equiv", "")
    shot = tmp_path / "shot.png"
    prof = tempfile.mkdtemp()
    r = subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                        "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={prof}",
                        "--window-size=1400,2200", "--virtual-time-budget=10000", f"--screenshot={shot}", "--enable-logging=stderr", "--v=0",
                        page.as_uri()], capture_output=True, text=True, timeout=180)
    shutil.rmtree(prof, ignore_errors=True)
    console = [ln for ln in r.stderr.splitlines() if "CONSOLE" in ln and ("ERROR" in ln or "error" in ln.lower())]
    assert console == [], console
    assert shot.exists() and shot.stat().st_size > 20_000
    from matplotlib.image import imread

    img = imread(shot)
    assert img.std() > 0.05  # not a blank page: the figures are drawn
    keep = os.environ.get("BMCTL_KEEP_SCREENSHOT")
    if keep:
        shutil.copyfile(shot, keep)


# --- a trial is a campaign with a simulated mill -------------------------------------------------------
@pytest.mark.slow
def test_trial_as_campaign_gives_the_trial_trajectory(tmp_path):
    from bmctl.campaign.simulated import run_as_campaign

    from .scenarios import lqr_scenario
    from bmctl.trial import run_trial

    sc = lqr_scenario(tmp_path / "scenario.toml")
    summary = run_trial(sc, tmp_path / "trial", seed=11)
    rows = run_as_campaign(sc, tmp_path / "campaign", seed=11)
    data = np.genfromtxt(tmp_path / "trial" / "trajectory.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert len(rows) == data.size == 4
    np.testing.assert_allclose([r["rpm"] for r in rows], data["rpm"], rtol=1e-5)
    np.testing.assert_allclose([r["true"]["s_mean_um"] for r in rows], data["true_s_mean_um"], rtol=1e-5)
    np.testing.assert_allclose([r["estimate"]["s_mean_um"] for r in rows], data["est_s_mean_um"], rtol=1e-5)
    for k, v in summary["final_estimate"].items():  # full precision at the end
        assert rows[-1]["estimate"][k] == v, k


def test_package_verbs_stay_functions_after_every_submodule_is_imported():
    """No submodule of bmctl.campaign shadows a verb of the package (``report`` once did)."""
    import importlib
    import pkgutil

    import bmctl.campaign as pkg

    for m in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"bmctl.campaign.{m.name}")
    for verb in pkg.__all__:
        assert callable(getattr(pkg, verb)) and not isinstance(getattr(pkg, verb), type(pkg)), verb


# --- damaged or edited databases, out-of-range flags (found by the campaign fuzz, tests/fuzzlib.py) ----------
@pytest.fixture(scope="module")
def fresh_campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("fresh") / "c"
    _init(d)
    return d


@pytest.mark.parametrize("damage, named", [
    ("DROP TABLE actions", "table actions missing"),
    ("DROP TABLE meta", "table meta missing"),
    ("UPDATE meta SET value = 'abc' WHERE key = 'hours'", "meta 'hours'"),
    ("UPDATE meta SET value = '{}' WHERE key = 'hours'", "meta 'hours'"),
    ("UPDATE meta SET value = X'00' WHERE key = 'particles'", "meta 'particles'"),
    ("UPDATE estimator_states SET t_h = 'abc'", "estimator_states row 1: t_h"),
    ("UPDATE estimator_states SET estimate = 'abc'", "estimator_states row 1: estimate"),
    ("UPDATE estimator_states SET state = 'abc'", "estimator_states row 1: state"),
])
@pytest.mark.parametrize("verb", ["status", "advise", "log"])
def test_damaged_database_is_one_line_naming_the_field(fresh_campaign, tmp_path, capsys, damage, named, verb):
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute(damage)
    con.commit()
    con.close()
    argv = ["campaign", verb, str(d)] + (["--rpm", "300", "--hours", "0.5"] if verb == "log" else [])
    assert main(argv) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and db.DB_NAME in err[0] and named in err[0], err


def test_actions_time_far_beyond_the_batch_is_refused(fresh_campaign, tmp_path, capsys):
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    cp.log(d, 300.0, 0.5)
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute("UPDATE actions SET t1_h = 1e308")
    con.commit()
    con.close()
    assert main(["campaign", "decide", str(d), "--accept"]) == 2
    assert "actions row 1: t1_h" in capsys.readouterr().err


def test_out_of_range_campaign_flags_are_refused(fresh_campaign, tmp_path):
    with pytest.raises(InputError, match="^hours: "):  # the argument, as the Python call named it
        _init(tmp_path / "a", hours=1e300)
    with pytest.raises(InputError, match="^temperature_max_c: "):
        _init(tmp_path / "b", temperature_max_c=1e9)
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    with pytest.raises(InputError, match="^rpm 5000: above the mill's rpm_max"):
        cp.log(d, 5000.0, 0.5)
    assert cp.status(d)["counts"]["actions"] == 0


def test_an_advice_at_the_batch_end_keeps_the_campaign_readable(tmp_path, capsys):
    """Advising once the whole batch is logged stores the end state (a zero-length next interval);
    every verb still reads the campaign (the check once refused that advice and locked the campaign
    out of its own report) and decide says the batch is over."""
    d = tmp_path / "c"
    _init(d, hours=1.0)
    cp.log(d, 300.0, 1.0)
    assert main(["campaign", "advise", str(d)]) == 0
    assert "next: batch finished" in capsys.readouterr().out
    for verb in (["status"], ["advise"], ["report", "--out", str(tmp_path / "r.html")]):
        assert main(["campaign", verb[0], str(d), *verb[1:]]) == 0, verb
    capsys.readouterr()
    assert main(["campaign", "decide", str(d), "--accept"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the batch ended at 1 h: nothing left to decide" in err[0]


@pytest.mark.parametrize("dest", ["campaign.sqlite", "inputs/alni-1to1-300rpm-lab.toml", "inputs/new.html"])
def test_the_report_never_overwrites_the_campaigns_own_files(tmp_path, capsys, dest):
    d = tmp_path / "c"
    _init(d)
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    assert main(["campaign", "report", str(d), "--out", str(d / dest)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the campaign's own file" in err[0]
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before
    assert main(["campaign", "status", str(d)]) == 0


@pytest.mark.parametrize("table", ["s_um,r\n40,0.9999999995\n40,0.2\n", "area_um2,perimeter_um\n1,1e10\n"])
def test_a_table_the_reader_takes_keeps_the_campaign_readable(tmp_path, capsys, table):
    """r just below 1 is a valid particle (the reader takes r in [0, 1)); the database check once
    stopped at 0.999999999 and refused the campaign after the sample was stored."""
    d = tmp_path / "c"
    _init(d)
    (tmp_path / "t.csv").write_text(table, encoding="utf-8")
    assert main(["campaign", "sample", str(d), "--at-h", "0", str(tmp_path / "t.csv")]) == 0
    assert main(["campaign", "status", str(d)]) == 0, capsys.readouterr().err


@pytest.fixture(scope="module")
def advised_campaign(tmp_path_factory):
    """A campaign with a logged interval, a sample and an advice (every table has rows)."""
    d = tmp_path_factory.mktemp("advised") / "c"
    _init(d)
    cp.log(d, 300.0, 0.5, temperature_c=40.0)
    cp.sample(d, 0.5, [ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"])
    cp.advise(d)
    return d


@pytest.mark.parametrize("damage, named", [
    ("DELETE FROM estimator_states", "the prior"),
    ("DELETE FROM estimator_states WHERE t_h < 0", "the prior"),
    ("DELETE FROM particles", "samples row 1: no particles"),
    ("UPDATE particles SET sample_id = 99", "samples row 1: no particles"),
    ("UPDATE estimator_states SET estimate = json_set(estimate, '$.gamma_mult', 'x')", "'gamma_mult'"),
    ("UPDATE estimator_states SET estimate = json_set(estimate, '$.t_h', 'x')", "'t_h'"),
    ("UPDATE estimator_states SET estimate = json_remove(estimate, '$.d50_um')", "d50_um: missing"),
    ("UPDATE estimator_states SET estimate = json_remove(estimate, '$.d50_um_q05')", "d50_um_q05: missing"),
    ("UPDATE estimator_states SET estimate = json_set(estimate, '$.d50_um', json('null'))", "'d50_um'"),
    ("UPDATE plans SET advice = json_set(advice, '$.schedule', json('[{\"rpm\": \"x\"}]'))", "schedule"),
    ("UPDATE plans SET advice = json_remove(advice, '$.estimate')", "estimate"),
    ("UPDATE plans SET advice = json_set(advice, '$.target', 'x')", "target"),
    ("UPDATE plans SET advice = json_set(advice, '$.notes', 5)", "notes"),
])
@pytest.mark.parametrize("verb", ["status", "advise", "report", "sample"])
def test_edited_rows_are_refused_in_one_line_by_every_verb(advised_campaign, tmp_path, capsys, damage, named, verb):
    """Edits the table and column checks let through once reached the verbs as tracebacks
    (TypeError in the estimate's node, KeyError or a format error in the report)."""
    d = tmp_path / "c"
    shutil.copytree(advised_campaign, d)
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute(damage)
    con.commit()
    con.close()
    extra = {"report": ["--out", str(tmp_path / "r.html")],
             "sample": ["--at-h", "0.5", str(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv")]}
    assert main(["campaign", verb, str(d), *extra.get(verb, [])]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    assert len(err) == 1 and db.DB_NAME in err[0] and named in err[0], err


def test_one_file_given_twice_is_not_a_sample_twice_its_size(fresh_campaign, tmp_path, capsys):
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    csv = ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"
    assert main(["campaign", "sample", str(d), "--at-h", "0", str(csv), str(csv)]) == 2
    assert "given twice" in capsys.readouterr().err
    assert cp.status(d)["counts"]["samples"] == 0


def test_status_says_the_advice_as_advise_does(fresh_campaign, tmp_path, capsys):
    """status once printed "latest advice: 370 rpm, milling 0.167"; it says the minutes, as advise does,
    counts the decisions a later one replaced and dates each deviation."""
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    cp.advise(d)
    cp.decide(d, True)
    cp.decide(d, False, rpm=250.0)
    cp.log(d, 250.0, 0.5)
    capsys.readouterr()
    assert main(["campaign", "status", str(d)]) == 0
    out = capsys.readouterr().out
    assert "2 decisions (1 replaced by a later one)" in out
    assert "latest advice at 0 h: 300 rpm, mill 30 min, rest 0 min (superseded by the log); rejected" in out
    assert "at 0 h: deviation from the recommendation (advice rejected): rpm 250 (recommended 300)" in out


def test_a_micrograph_under_a_path_that_is_not_utf8_is_sampled(fresh_campaign, tmp_path, capsys):
    """A file name's bytes need not be UTF-8; the particles' image column once took the raw
    path and the insert failed with a traceback."""
    d = tmp_path / "c"
    shutil.copytree(fresh_campaign, d)
    odd = tmp_path / os.fsdecode(b"bad\xff\xfename")
    odd.mkdir()
    shutil.copy(ROOT / "examples" / "micrograph-2h.tif", odd / "m.tif")
    shutil.copy(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv", odd / "t.csv")
    assert main(["campaign", "sample", str(d), "--at-h", "0", str(odd / "m.tif")]) == 0, capsys.readouterr().err
    assert main(["campaign", "sample", str(d), "--at-h", "0", str(odd / "t.csv")]) == 0, capsys.readouterr().err
    assert main(["campaign", "report", str(d), "--out", str(tmp_path / "r.html")]) == 0


def test_the_ceiling_is_not_named_when_a_plan_under_it_comes_closer(tmp_path):
    """A fresh campaign to a growth target: a two-phase plan under the ceiling ends nominally closest
    and the filter's spread picks another; a schedule over the ceiling that beats the plan (not the
    two-phase one) was once named as if the ceiling kept the plan from the target."""
    d = tmp_path / "c"
    cp.init(d, CARD, ROOT / "controllers" / "mpc-default.toml", {"s_mean_um": 45.0}, hours=6.0, particles=1000)
    rng = np.random.default_rng(1)
    s, r = rng.lognormal(np.log(40.0), 0.1, 300), rng.beta(2.0, 60.0, 300)
    cp.sample(d, 0.0, [ParticleTable.from_size_aspect(s, r)])
    adv = cp.advise(d)
    spread = [b for b in adv["binding"] if b.startswith("the filter's spread")]
    assert spread, adv["binding"]  # the situation: a closer plan under the ceiling exists
    assert not any("closer schedules run over it" in b for b in adv["binding"]), adv["binding"]


def test_an_estimate_the_samples_leave_uncertain_is_noted(tmp_path):
    """Samples that disagree with the model (no growth where the card predicts it) widen the
    filter's interval of the mean size past a factor of two; advise says so in a note."""
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"s_mean_um": 45.0}, hours=6.0, particles=1000, seed=3)

    def table(mean, seed):
        rng = np.random.default_rng(seed)
        return ParticleTable.from_size_aspect(rng.lognormal(np.log(mean), 0.1, 300), rng.beta(2.0, 60.0, 300))

    cp.sample(d, 0.0, [table(40.0, 0)])
    assert not cp.advise(d)["notes"]  # one sample of the feed: a narrow estimate, nothing to note
    cp.log(d, 300.0, 0.5)
    cp.sample(d, 0.5, [table(40.0, 1)])
    cp.log(d, 280.0, 0.5)
    cp.log(d, 0.0, 0.5)
    cp.sample(d, 1.5, [table(33.0, 2)])
    cp.log(d, 280.0, 0.5)
    adv = cp.advise(d)
    est = adv["estimate"]
    assert est["s_mean_um_q95"] > 2 * est["s_mean_um_q05"]
    assert any(n.startswith("the estimate is uncertain: s_mean_um") for n in adv["notes"]), adv["notes"]


def test_status_and_report_read_a_campaign_the_user_may_not_write(advised_campaign, tmp_path, capsys, monkeypatch):
    """An archived campaign (a read-only file or share): the verbs that only read open it read-only;
    one that records says it is read-only (it said "cannot be read as a bmctl campaign database")."""
    d = tmp_path / "c"
    shutil.copytree(advised_campaign, d)

    def locked(path):  # what sqlite3 says when the user may not write the file or its folder
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(db, "_connect", locked)
    assert main(["campaign", "status", str(d)]) == 0
    assert main(["campaign", "report", str(d), "--out", str(tmp_path / "r.html")]) == 0
    capsys.readouterr()
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "read-only for this user" in err[0], err


def test_the_readme_walkthrough_says_why_it_rests_not_that_the_target_is_out_of_reach(tmp_path, capsys):
    """The README's campaign: a reading at the 60 degC ceiling makes every plan rest first, and the plan
    shown rests to the batch end; why once said the target is NOT reachable."""
    d = tmp_path / "run1"
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller",
                 str(ROOT / "controllers" / "mpc-default.toml"), "--target", "d50_um=45", "--hours", "12",
                 "--temperature-max-c", "60"]) == 0
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5", "--temperature-c", "60.1"]) == 0
    assert main(["campaign", "sample", str(d), "--at-h", "0.5",
                 str(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv")]) == 0
    capsys.readouterr()
    assert main(["campaign", "advise", str(d)]) == 0
    out = capsys.readouterr().out
    assert "binding: vial-temperature ceiling (60 °C) now:" in out
    assert "why: target d50_um = 45: not judged at this advice" in out and "NOT reachable" not in out


def test_a_ceiling_below_the_ambient_is_refused_at_init(tmp_path):
    with pytest.raises(InputError, match="^temperature_max_c: 20 °C is not above the card's ambient"):
        _init(tmp_path / "c", temperature_max_c=20.0)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("ctrl", [RECIPE, LQR, ROOT / "controllers" / "mpc-default.toml"], ids=["recipe", "lqr", "mpc"])
def test_a_batch_under_the_minimum_milling_period_is_refused_at_init(tmp_path, capsys, ctrl):
    """--hours 0.05 (3 min) under the 5-min minimum milling period: refused as trial and design refuse
    it, one line naming --hours, nothing created (it was accepted and advised 3-min milling)."""
    d = tmp_path / "c"
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(ctrl), "--target",
                 "s_mean_um=45", "--hours", "0.05"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("bmctl: error: --hours: a batch of 0.05 h (3 min) is shorter"), err
    assert not d.exists()
