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
    page = (d / "r.html").read_text()
    p = _Tags()
    p.feed(page)
    assert p.tags <= {"html", "head", "meta", "title", "style", "body", "h1", "h2", "p", "b", "figure", "img",
                      "figcaption", "table", "thead", "tbody", "tr", "th", "td"}, p.tags
    assert p.attrs <= {"lang", "charset", "alt", "src"}, p.attrs
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
    p.feed((d / "r.html").read_text())
    assert "script" not in p.tags and not any(a.startswith("on") for a in p.attrs), (p.tags, p.attrs)
