"""Hostile inputs of the second round: crafted databases and trial folders, deep nesting, special
files, names that would become paths, HTML injection, unbounded work, multi-line messages.

Each test is one known reproducer: exit 2 with one line naming the file, flag or field, or (for a
legitimate input) a correct run; tests/test_fuzz.py draws many more of each class."""

from __future__ import annotations

import html.parser
import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.cli import main

from . import fuzzlib

ROOT = fuzzlib.ROOT
LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


def _err(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    return err[0]


@pytest.fixture(scope="module")
def logged_campaign(tmp_path_factory):
    """A 2 h recipe campaign with a 0.5 h log, a sample and an advice."""
    d = tmp_path_factory.mktemp("logged") / "c"
    cp.init(d, LAB, RECIPE, "d50_um=45", hours=2.0, particles=100)
    cp.log(d, 300.0, 0.5, 1.0, 40.0)
    t = d.parent / "t.csv"
    t.write_bytes(fuzzlib._table_csv(__import__("random").Random(0)))
    cp.sample(d, 0.5, [str(t)])
    cp.advise(d)
    return d


def _copy(src: Path, tmp_path: Path) -> Path:
    d = tmp_path / "c"
    shutil.copytree(src, d)
    return d


def _sql(d: Path, q: str, *args) -> None:
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute(q, args)
    con.commit()
    con.close()


class _Tags(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.attrs = set(), set()

    def handle_starttag(self, tag, attrs):
        self.tags.add(tag)
        self.attrs |= {a for a, _ in attrs}


# --- HTML: every value escaped at render ---------------------------------------------------------------

INJECT = '<script>alert(1)</script><img src=x onerror="alert(2)">'


def test_report_escapes_every_advice_field(logged_campaign, tmp_path, capsys):
    d = _copy(logged_campaign, tmp_path)
    con = sqlite3.connect(str(d / db.DB_NAME))
    advice = json.loads(con.execute("SELECT advice FROM plans ORDER BY id DESC LIMIT 1").fetchone()[0])
    con.close()
    advice["binding"] = [INJECT]  # text fields: stored as they are, escaped when shown
    _sql(d, "UPDATE plans SET advice = ?", json.dumps(advice))
    _sql(d, "UPDATE actions SET deviation = ?", INJECT)
    _sql(d, "UPDATE samples SET sources = ?", json.dumps([INJECT]))
    assert main(["campaign", "report", str(d), "--out", str(d / "r.html")]) == 0
    page = (d / "r.html").read_text(encoding="utf-8")
    p = _Tags()
    p.feed(page)
    assert "script" not in p.tags and "iframe" not in p.tags and not any(a.startswith("on") for a in p.attrs)
    assert fuzzlib.html_problems(d) == []  # only the tags and attributes of bmctl's templates
    assert "&lt;script&gt;" in page


@pytest.mark.parametrize("field", ["mill_min", "rest_min", "reachable", "t_h"])
def test_report_never_writes_markup_from_a_crafted_advice(logged_campaign, tmp_path, capsys, field):
    d = _copy(logged_campaign, tmp_path)
    con = sqlite3.connect(str(d / db.DB_NAME))
    advice = json.loads(con.execute("SELECT advice FROM plans ORDER BY id DESC LIMIT 1").fetchone()[0])
    con.close()
    if field == "reachable":
        advice["reachable"] = {INJECT: True}
    elif field == "t_h":
        advice["t_h"] = INJECT
    else:
        advice["next"][field] = INJECT
    _sql(d, "UPDATE plans SET advice = ?", json.dumps(advice))
    rc = main(["campaign", "report", str(d), "--out", str(d / "r.html")])
    if rc == 2:  # refused on load: the advice is not what advise writes
        assert "campaign.sqlite: plans row 1: advice" in _err(capsys)
        assert not (d / "r.html").exists()
        return
    assert rc == 0
    p = _Tags()
    p.feed((d / "r.html").read_text(encoding="utf-8"))
    assert "script" not in p.tags and not any(a.startswith("on") for a in p.attrs), (p.tags, p.attrs)


# --- nesting: TOML and JSON bounded in depth before parsing -------------------------------------------

DEEP = fuzzlib.deep_toml_value(1000)


@pytest.mark.parametrize("argv, name", [
    (["card", "show", "@card.toml"], "card.toml"),
    (["simulate", "@card.toml", "--hours", "0.1", "--out", "@o"], "card.toml"),
    (["whatif", str(LAB), "@s.toml", "--out", "@o"], "s.toml"),
    (["design", str(LAB), "--target", "s_mean_um=30", "--controller", "@c.toml", "--out", "@o"], "c.toml"),
    (["trial", "@sc.toml", "--out", "@o"], "sc.toml"),
])
def test_toml_nested_1000_deep_is_one_line(tmp_path, capsys, argv, name):
    (tmp_path / "card.toml").write_text(LAB.read_text(encoding="utf-8") + f"\nzz = {DEEP}\n", encoding="utf-8")
    (tmp_path / "s.toml").write_text(f"zz = {DEEP}\n[[segment]]\nhours = 0.1\nrpm = 300\n", encoding="utf-8")
    (tmp_path / "c.toml").write_text(RECIPE.read_text(encoding="utf-8") + f"\nzz = {DEEP}\n", encoding="utf-8")
    (tmp_path / "sc.toml").write_text(fuzzlib.SCENARIO_BASE.format(model=LAB, controller=RECIPE).replace(
        'hours = 0.5', f'hours = 0.5\nzz = {DEEP}'), encoding="utf-8")
    argv = [a.replace("@", str(tmp_path) + "/") if a.startswith("@") else a for a in argv]
    assert main(argv) == 2
    line = _err(capsys)
    assert name in line and "nested 1000 levels deep" in line, line
    assert len(line) < 400


def test_nesting_depth_ignores_brackets_in_strings_and_comments():
    from bmctl.io import nesting_depth

    assert nesting_depth('a = "[[[[" # [[[[\nb = [[1]]\n[t]\nc = \'\'\'[[[\n[[\'\'\'', toml=True) == 2
    assert nesting_depth('{"a": "[[\\"[[", "b": [[[]]]}') == 4


@pytest.fixture(scope="module")
def stopped_trial(tmp_path_factory):
    """The fuzz's resume scenario (three 0.5 h steps, open loop) stopped after one step."""
    from bmctl.trial import run_trial

    root = tmp_path_factory.mktemp("trial")
    sc = root / "resume.toml"
    sc.write_text(fuzzlib.RESUME_SCENARIO, encoding="utf-8")
    run_trial(sc, root / "t", max_steps=1)
    return sc, root / "t"


def _resume(stopped_trial, tmp_path, damage) -> tuple[list[str], Path]:
    sc, src = stopped_trial
    d = tmp_path / "t"
    shutil.copytree(src, d)
    damage(d)
    return ["trial", str(sc), "--resume", str(d), "--no-progress"], d


def _rewrite_json(d: Path, text: str) -> None:
    from bmctl.checkpoint import JSON_KEY
    import numpy as np

    with np.load(d / "checkpoint.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[JSON_KEY] = np.array(text)
    with open(d / "checkpoint.npz", "wb") as fh:
        np.savez(fh, **arrays)


@pytest.mark.parametrize("what", ["json-deep", "npy-huge", "npy-beyond-data", "meta-deep"])
def test_crafted_checkpoint_is_refused_before_allocation(stopped_trial, tmp_path, capsys, what):
    def damage(d):
        if what == "json-deep":
            _rewrite_json(d, fuzzlib.deep_json())
        elif what == "meta-deep":
            (d / "trial.json").write_text(fuzzlib.deep_json(), encoding="utf-8")
        else:
            shape = (10**12,) if what == "npy-huge" else (1000,)
            (d / "checkpoint.npz").write_bytes(fuzzlib.npz_with({"__json__.npy": fuzzlib.npy_bomb((), "<U10", b"x" * 40),
                                                                 "plant/s.npy": fuzzlib.npy_bomb(shape)}))
    argv, d = _resume(stopped_trial, tmp_path, damage)
    assert main(argv) == 2
    line = _err(capsys)
    assert ("trial.json" if what == "meta-deep" else "checkpoint.npz") in line, line
    if what != "npy-beyond-data":
        assert "nested 100000 levels deep" in line or "declares a (1000000000000,) array" in line, line


# --- special files: FIFOs and devices are refused, never waited on -----------------------------------

@pytest.mark.parametrize("name", ["trial.json", "checkpoint.npz", "trajectory.csv"])
@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_special_file_in_a_trial_folder_is_refused(stopped_trial, tmp_path, capsys, name, kind):
    import os

    def damage(d):
        (d / name).unlink()
        if kind == "fifo":
            os.mkfifo(d / name)
        else:
            (d / name).symlink_to("/dev/zero")
    argv, d = _resume(stopped_trial, tmp_path, damage)
    assert main(argv) == 2
    line = _err(capsys)
    assert name in line and "not a regular file" in line, line


# --- the campaign database: content validated on load ------------------------------------------------

def _latest_estimate(d: Path) -> dict:
    con = sqlite3.connect(str(d / db.DB_NAME))
    e = json.loads(con.execute("SELECT estimate FROM estimator_states ORDER BY t_h DESC LIMIT 1").fetchone()[0])
    con.close()
    return e


@pytest.mark.parametrize("damage, named", [
    ("advice-deep", "plans row 1: advice: nested 100000 levels deep"),
    ("estimate-deep", "estimator_states row 1: estimate: nested 100000 levels deep"),
    ("no-s_std_um", "estimate: s_std_um: missing"),
    ("nan-estimate", "'s_mean_um' = nan: not finite"),
    ("nan-band", "s_std_um_q95"),
    ("advice-rpm-text", "plans row 1: advice: next.rpm"),
    ("inputs-path", "meta 'inputs'"),
    ("inputs-outside", "leads outside"),
])
@pytest.mark.parametrize("verb", ["status", "advise", "decide", "report"])
def test_crafted_database_is_refused_by_every_verb(logged_campaign, tmp_path, capsys, damage, named, verb):
    d = _copy(logged_campaign, tmp_path)
    if damage == "advice-deep":
        _sql(d, "UPDATE plans SET advice = ?", fuzzlib.deep_json())
    elif damage == "estimate-deep":
        _sql(d, "UPDATE estimator_states SET estimate = ? WHERE rowid = 1", fuzzlib.deep_json())
    elif damage in ("no-s_std_um", "nan-estimate", "nan-band"):
        e = _latest_estimate(d)
        if damage == "no-s_std_um":
            del e["s_std_um"]
        elif damage == "nan-estimate":
            e["s_mean_um"] = float("nan")
        else:
            e["s_std_um_q95"] = float("inf")
        _sql(d, "UPDATE estimator_states SET estimate = ? WHERE t_h = (SELECT MAX(t_h) FROM estimator_states)",
             json.dumps(e))
    elif damage == "advice-rpm-text":
        con = sqlite3.connect(str(d / db.DB_NAME))
        a = json.loads(con.execute("SELECT advice FROM plans").fetchone()[0])
        con.close()
        a["next"]["rpm"] = "300"
        _sql(d, "UPDATE plans SET advice = ?", json.dumps(a))
    else:  # a crafted input path: a file elsewhere, with its own checksum
        other = tmp_path / "elsewhere.toml"
        other.write_text(LAB.read_text(encoding="utf-8"), encoding="utf-8")
        import hashlib

        con = sqlite3.connect(str(d / db.DB_NAME))
        inp = json.loads(con.execute("SELECT value FROM meta WHERE key = 'inputs'").fetchone()[0])
        con.close()
        f = str(other) if damage == "inputs-path" else "inputs/../../elsewhere.toml"
        inp["card"] = {"source": str(other), "file": f, "sha256": hashlib.sha256(other.read_bytes()).hexdigest()}
        _sql(d, "UPDATE meta SET value = ? WHERE key = 'inputs'", json.dumps(inp))
    argv = ["campaign", verb, str(d)] + (["--accept"] if verb == "decide" else [])
    before = sorted(p.name for p in d.iterdir())
    assert main(argv) == 2
    line = _err(capsys)
    assert named in line, line
    assert sorted(p.name for p in d.iterdir() if not p.name.startswith("campaign.sqlite-")) == \
        [n for n in before if not n.startswith("campaign.sqlite-")]


# --- names never become paths; files named inside a file stay in its folder ---------------------------

def _history(tmp_path: Path, name: str = "run", table: str = "t.csv") -> Path:
    import random

    (tmp_path / "h").mkdir(exist_ok=True)
    (tmp_path / "h" / "t.csv").write_bytes(fuzzlib._table_csv(random.Random(0), 60))
    h = tmp_path / "h" / "run.toml"
    h.write_text(f'name = {json.dumps(name)}\n[[segment]]\nhours = 1.0\nrpm = 300\n'
                 f'[[sample]]\nt_h = 1.0\ntable = {json.dumps(table)}\n', encoding="utf-8")
    return h


@pytest.mark.parametrize("table", ["/etc/passwd", "../secret.csv", "../../../../../../etc/passwd"])
def test_a_history_cannot_name_a_file_outside_its_folder(tmp_path, capsys, table):
    (tmp_path / "secret.csv").write_text("TOPSECRET,line\n1,2\n", encoding="utf-8")
    h = _history(tmp_path, table=table)
    assert main(["calibrate", str(LAB), str(h), "--out", str(tmp_path / "o"), "--workers", "0"]) == 2
    line = _err(capsys)
    assert "run.toml: sample[0].table" in line and "TOPSECRET" not in line and "root:" not in line, line


def test_a_history_name_never_becomes_a_path(tmp_path):
    from bmctl.calibrate.history import load_history
    from bmctl.io import name_part

    h = load_history(_history(tmp_path, name="../../../X"))
    assert h.name == "../../../X" and name_part(h.name) == "X"
    assert "/" not in name_part("a/b\\c") and name_part("..") == "unnamed"


# --- ranges shared by every command --------------------------------------------------------------------

@pytest.mark.parametrize("argv, needle", [
    (["linearize", str(LAB), "--at-hours", "1e300"], "--at-hours: must be 0 or in [1 s, 1000 h]"),
    (["linearize", str(LAB), "--at-hours", "2000"], "--at-hours: must be 0 or in [1 s, 1000 h]"),
    (["linearize", str(LAB), "--at-hours", "1e6"], "--at-hours"),
    (["linearize", str(LAB), "--horizon", "1e300"], "--horizon"),
    (["simulate", str(LAB), "--rpm", "1e20"], "--rpm: must be <= 2000"),
    (["compare", "@a.csv", "--model", str(LAB), "--at-h", "5000"], "--at-h"),
])
def test_time_and_speed_flags_share_one_range(tmp_path, capsys, argv, needle):
    import random

    (tmp_path / "a.csv").write_bytes(fuzzlib._table_csv(random.Random(0)))
    argv = [a.replace("@", str(tmp_path) + "/") if a.startswith("@") else a for a in argv]
    assert main(argv + ["--out", str(tmp_path / "o")]) == 2
    assert needle in _err(capsys)


@pytest.mark.parametrize("edit, needle", [
    ("[mill]\nrpm_min_milling = 1e20\n", "mill.rpm_min_milling"),
    ("rest_min = 10000.0\n", "rest_min"),
])
def test_controller_fields_share_the_card_ranges(tmp_path, capsys, edit, needle):
    ctrl = tmp_path / "c.toml"
    text = (ROOT / "controllers" / "recipe-400rpm-30-10.toml").read_text(encoding="utf-8")
    ctrl.write_text(text.replace("rest_min = 10.0\n", edit) if "rest_min" in edit else text + "\n" + edit, encoding="utf-8")
    sc = tmp_path / "sc.toml"
    sc.write_text(fuzzlib.SCENARIO_BASE.format(model=LAB, controller=ctrl), encoding="utf-8")
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert needle in _err(capsys)


def test_segment_hours_of_5e_324_is_refused(tmp_path, capsys):
    s = tmp_path / "s.toml"
    s.write_text("[[segment]]\nhours = 5e-324\nrpm = 300\n", encoding="utf-8")
    assert main(["whatif", str(LAB), str(s), "--out", str(tmp_path / "o")]) == 2
    assert "s.toml: segment[0].hours" in _err(capsys)


def test_campaign_log_of_a_picosecond_is_refused(logged_campaign, tmp_path, capsys):
    d = _copy(logged_campaign, tmp_path)
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "1e-12", "--temperature-c", "40"]) == 2
    assert "--hours: must be in [1 s, 1000 h]" in _err(capsys)
    assert cp.status(d)["counts"]["actions"] == 1


# --- one work estimate and one budget ---------------------------------------------------------------------

@pytest.mark.parametrize("argv, needle", [
    (["compare", "@a.csv", "--model", str(LAB), "--at-h", "12", "--particles", "10000000"], "--at-h/--particles"),
    (["compare", "@a.csv", "--model", str(LAB), "--at-h", "1", "--particles", "1000000000"], "--particles: must be"),
    (["estimate", str(LAB), "--samples", "@a.csv", "@a.csv", "--times", "0.5,1000", "--particles", "1000000"],
     "--times/--particles"),
    (["simulate", str(LAB), "--particles", "10000000", "--no-progress"], "--particles: the run would take"),
    (["calibrate", str(LAB), "@h/run.toml", "--particles", "1000000", "--replicates", "64", "--workers", "0"],
     "--particles/--replicates"),
])
def test_long_commands_are_estimated_and_refused_beyond_the_default_budget(tmp_path, capsys, monkeypatch, argv,
                                                                          needle):
    import random

    monkeypatch.delenv("BMCTL_BUDGET_CPU_H", raising=False)
    (tmp_path / "a.csv").write_bytes(fuzzlib._table_csv(random.Random(0)))
    _history(tmp_path)
    argv = [a.replace("@", str(tmp_path) + "/") if a.startswith("@") else a for a in argv]
    assert main(argv + ["--out", str(tmp_path / "o" / ("e.csv" if argv[0] == "estimate" else ""))]) == 2
    line = _err(capsys)
    assert needle in line and ("over the budget of 1 h" in line or "must be" in line), line
    assert not (tmp_path / "o").exists()


def test_the_budget_flag_allows_more(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("BMCTL_BUDGET_CPU_H", "1e-9")
    argv = ["simulate", str(LAB), "--hours", "0.05", "--particles", "200", "--no-progress", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "over the budget of 1e-09 h" in _err(capsys)
    assert main(argv + ["--budget-cpu-h", "1"]) == 0
    assert main(argv[:-2] + ["--out", str(tmp_path / "b")]) == 2  # the flag holds for its own command only


# --- one line, whatever the message quotes -------------------------------------------------------------

@pytest.mark.parametrize("case", ["key", "flag", "name", "long-name", "value"])
def test_errors_are_one_short_line(tmp_path, capsys, case):
    s = tmp_path / "s.toml"
    name = {"name": "a\nb", "long-name": "x" * 200_000}.get(case, "fz")
    extra = '"bo\\ngus" = 1\n' if case == "key" else ""
    hours = '"0.1\\n2"' if case == "value" else "0.1"
    s.write_text(f"name = {json.dumps(name)}\n{extra}[[segment]]\nhours = {hours}\nrpm = 300\n", encoding="utf-8")
    argv = ["whatif", str(LAB), str(s), "--out", str(tmp_path / "o")]
    if case == "flag":
        argv += ["--see\nds", "3"]
    assert main(argv) == 2
    line = _err(capsys)
    assert len(line) <= 700 and "s.toml" in line or "--see" in line, line


def test_calibrate_writes_only_inside_out_whatever_the_history_name(tmp_path, capsys, monkeypatch):
    import bmctl.moments.forcard as forcard

    # the calibrated card's own identification (minutes of plant runs) is not what is tested here
    monkeypatch.setattr(forcard, "identification_text", lambda *a, **k: "# coefficients not identified in this test\n")
    h = _history(tmp_path, name="../../../X")
    out = tmp_path / "deep" / "er" / "out"
    before = {p for p in tmp_path.rglob("*")}
    assert main(["calibrate", str(LAB), str(h), "--params", "gamma", "--particles", "100", "--workers", "0",
                 "--budget-cpu-h", "10", "--out", str(out)]) == 0
    capsys.readouterr()
    new = {p for p in tmp_path.rglob("*")} - before
    assert new and all(p == out or out in p.parents or p in out.parents for p in new), sorted(new)
    assert (out / "histograms-X.png").is_file()


@pytest.mark.parametrize("text", ['"' + '\\"' * 200_000, '"""' + "a" * 300_000 + "\\", ("'" + "x" * 5 + "\n") * 50_000,
                                  '["' + '\\"' * 200_000])
def test_unclosed_quotes_and_escapes_are_scanned_once(tmp_path, capsys, text):
    # every string alternative of the depth scan reaches its end when unclosed: no retry at each quote
    from bmctl.io import nesting_depth

    assert nesting_depth(text, toml=True) <= 1 and nesting_depth(text) <= 1
    (tmp_path / "card.toml").write_text(f"zz = {text}\n" + LAB.read_text(encoding="utf-8"), encoding="utf-8")
    assert main(["card", "show", str(tmp_path / "card.toml")]) == 2
    assert "card.toml" in _err(capsys)
