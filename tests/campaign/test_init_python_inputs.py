"""``bmctl.campaign.init`` called from Python checks ``seed`` and ``particles`` as ``bmctl campaign
init`` checks ``--seed`` and ``--particles``: whole numbers in the command's ranges, refused in one
line naming the argument before anything is written (not as a campaign that is "damaged or edited"
once written, nor as a raw ``ValueError``, nor cut or read from text or a flag). ``report`` whose
default output (``DIR/report.html``) is a link to the campaign's database names that file, not
the ``out`` argument the caller never gave."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import db, workflow
from bmctl.campaign.workflow import naming
from bmctl.cli import main
from bmctl.commands import campaign as command
from bmctl.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
TARGET = {"d50_um": 45.0}


def _init(d, **kw):
    return cp.init(d, CARD, RECIPE, TARGET, hours=2.0, **kw)


@pytest.fixture
def nothing_written(monkeypatch):
    """Fail the test if ``init`` gets as far as creating the campaign's database."""
    def create(*args, **kwargs):
        raise AssertionError("init created the database before refusing its arguments")

    monkeypatch.setattr(workflow.db, "create", create)


# (keyword arguments, the message's start)
BAD = [
    ({"particles": 300_000}, "particles: must be <= 200000 (got 300000); allowed: 50 to 200000"),
    ({"particles": 200_001}, "particles: must be <= 200000 (got 200001); allowed: 50 to 200000"),
    ({"particles": 49}, "particles: must be >= 50 (got 49); allowed: 50 to 200000"),
    ({"particles": "abc"}, "particles: not a whole number ('abc')"),
    ({"particles": "1000"}, "particles: not a whole number ('1000')"),
    ({"particles": 50.7}, "particles: not a whole number (50.7)"),
    ({"particles": float("nan")}, "particles: not a whole number (nan)"),
    ({"particles": float("inf")}, "particles: not a whole number (inf)"),
    ({"particles": None}, "particles: not a whole number (None)"),
    ({"particles": True}, "particles: not a whole number (True)"),
    ({"seed": -1}, "seed: must be >= 0 (got -1)"),
    ({"seed": True}, "seed: not a whole number (True)"),
    ({"seed": False}, "seed: not a whole number (False)"),
    ({"seed": np.bool_(True)}, "seed: not a whole number ("),
    ({"seed": "3"}, "seed: not a whole number ('3')"),
    ({"seed": b"3"}, "seed: not a whole number (b'3')"),
    ({"seed": 0.5}, "seed: not a whole number (0.5)"),
    ({"seed": None}, "seed: not a whole number (None)"),
]


@pytest.mark.parametrize("kw, start", BAD, ids=[f"{k}={v!r}" for kw, _ in BAD for k, v in kw.items()])
def test_a_bad_seed_or_particle_count_is_refused_before_anything_is_written(tmp_path, nothing_written, kw, start):
    d = tmp_path / "c"
    with pytest.raises(InputError) as exc:
        _init(d, **kw)
    msg = str(exc.value)
    assert msg.startswith(start) and "\n" not in msg and "meta" not in msg and "--" not in msg, msg
    assert not d.exists()


def test_within_the_command_the_flags_are_named(tmp_path, nothing_written):
    """The verbs run by ``bmctl campaign`` name ``--seed`` and ``--particles``."""
    with naming(command.FLAGS):
        with pytest.raises(InputError, match=r"^--particles: must be <= 200000 \(got 300000\)"):
            _init(tmp_path / "c", particles=300_000)
        with pytest.raises(InputError, match=r"^--seed: must be >= 0 \(got -1\)"):
            _init(tmp_path / "c", seed=-1)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("argv, start", [
    (["--particles", "300000"], "--particles: must be in [50, 200000] (got 300000)"),
    (["--particles", "50.7"], "--particles: not an integer: '50.7'"),
    (["--seed", "-1"], "--seed: must be >= 0 (got -1)"),
])
def test_the_command_refuses_as_before(tmp_path, capsys, argv, start):
    d = tmp_path / "c"
    rc = main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE),
               "--target", "d50_um=45", "--hours", "2", *argv])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("bmctl: error: " + start), err
    assert not d.exists()


def _rows(d) -> list[tuple]:
    """The prior's rows but their creation time (a second boundary between two inits would differ)."""
    con = sqlite3.connect(db.db_path(d))
    try:
        return con.execute("SELECT id, t_h, state, estimate FROM estimator_states ORDER BY id").fetchall()
    finally:
        con.close()


def test_whole_numbers_of_other_types_are_the_same_campaign(tmp_path):
    """Integers of numpy's types and integral floats are the integers: the same meta data and the
    same prior, bit for bit."""
    ref = _init(tmp_path / "ref", seed=3, particles=100)
    for i, kw in enumerate([{"seed": np.int64(3), "particles": np.int32(100)}, {"seed": 3.0, "particles": 100.0}]):
        d = tmp_path / f"c{i}"
        meta = _init(d, **kw)
        assert type(meta["seed"]) is int and type(meta["particles"]) is int
        assert {k: v for k, v in meta.items() if k != "created_at"} == \
            {k: v for k, v in ref.items() if k != "created_at"}
        assert _rows(d) == _rows(tmp_path / "ref")


def test_the_bounds_are_allowed(tmp_path):
    assert _init(tmp_path / "lo", seed=0, particles=50)["particles"] == 50
    assert _init(tmp_path / "big", seed=2**40, particles=50)["seed"] == 2**40


@pytest.fixture
def linked(tmp_path):
    """A campaign whose ``report.html`` is a link to its database."""
    d = tmp_path / "c"
    _init(d, particles=100)
    os.symlink(db.DB_NAME, d / "report.html")
    return d


def test_a_default_report_path_on_the_database_names_the_file(linked):
    with pytest.raises(InputError) as exc:
        cp.report(linked)
    msg = str(exc.value)
    assert msg.startswith(f"{linked / 'report.html'}: the default output is the campaign's own file"), msg
    assert msg.endswith("choose another path (out)") and "\n" not in msg, msg
    with pytest.raises(InputError, match=r"^out: "):  # a path given is named as the argument, as before
        cp.report(linked, linked / "report.html")
    assert os.readlink(linked / "report.html") == db.DB_NAME


def test_the_command_names_the_file_and_its_flag(linked, capsys):
    assert main(["campaign", "report", str(linked)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"bmctl: error: {linked / 'report.html'}: ") and \
        err[0].endswith("choose another path (--out)"), err
    assert main(["campaign", "report", str(linked), "--out", str(linked / "report.html")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("bmctl: error: --out: "), err
