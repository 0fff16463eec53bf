"""A campaign's estimator nodes, repeated samples, ``init``'s input copies and the stored scale:
one node per observation time however a float rounds it, an image and its ``bmctl measure``
table are one sample, ``init`` never replaces a file of the user's, and a scale no image used
is not stored."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from bmctl.campaign import db
from bmctl.campaign import workflow as wf
from bmctl.cli import main

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
TABLE = ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"
IMAGE = ROOT / "examples" / "micrograph-2h.tif"


def _init(d: Path, hours: str = "2") -> None:
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE),
                 "--target", "d50_um=45", "--hours", hours, "--particles", "60"]) == 0


def _rows(d: Path, sql: str) -> list:
    con = sqlite3.connect(str(Path(d) / db.DB_NAME))
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def _nodes(d: Path) -> list:
    return _rows(d, "SELECT t_h, state, estimate FROM estimator_states ORDER BY t_h, id")


def _err_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


# --- one node per observation time -----------------------------------------------------------------
def test_node_times_join_times_a_rounding_apart():
    end = 0.1 + 0.2  # 0.30000000000000004
    assert wf._node_times([0.1, end], [0.3, end, 0.1]) == {0.3: end, end: end, 0.1: 0.1}
    assert wf._node_times([0.5], [0.75, 0.75 + 1e-12, 1.0]) == {0.75: 0.75, 0.75 + 1e-12: 0.75, 1.0: 1.0}
    assert wf._node_times([0.5, 1.0], [0.5, 0.5 + 2e-9]) == {0.5: 0.5, 0.5 + 2e-9: 0.5 + 2e-9}  # EPS_H apart: two


@pytest.mark.parametrize("order", ["log first", "sample first"])
def test_a_sample_a_rounding_off_an_action_end_is_one_node_with_its_reading(tmp_path, capsys, order):
    """A sample at 0.3 h and the reading logged at 0.1 + 0.2 h are one observation time: one node,
    updated with both, the same state as a sample entered at the logged clock's value."""
    dirs = {}
    for name, at in (("exact", repr(0.1 + 0.2)), ("typed", "0.3")):
        d = dirs[name] = tmp_path / name
        _init(d)
        assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.1"]) == 0
        if order == "sample first":  # held until the log reaches it
            assert main(["campaign", "sample", str(d), "--at-h", at, str(TABLE)]) == 0
        assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.2", "--temperature-c", "50"]) == 0
        if order == "log first":
            assert main(["campaign", "sample", str(d), "--at-h", at, str(TABLE)]) == 0
    typed, exact = _nodes(dirs["typed"]), _nodes(dirs["exact"])
    assert [t for t, _, _ in typed] == [-1.0, 0.1, 0.1 + 0.2]  # not 0.3 and 0.30000000000000004 apart
    assert typed == exact  # the same state, bit for bit
    if order == "log first":  # stored at its node's time
        assert _rows(dirs["typed"], "SELECT t_h FROM samples") == [(0.1 + 0.2,)]


# --- an image and its table ---------------------------------------------------------------------------
@pytest.mark.parametrize("image_first", [True, False])
def test_an_image_and_its_measure_table_are_one_sample(tmp_path, capsys, image_first):
    """``bmctl measure``'s table of a micrograph holds its particles to 7 digits: entered after
    the micrograph (or before it) it is the same sample, refused in one line naming both."""
    table = tmp_path / "meas" / "table.csv"
    assert main(["measure", str(IMAGE), "--out", str(table), "--no-progress"]) == 0
    d = tmp_path / "c"
    _init(d, hours="3")
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "1"]) == 0
    first, second = (IMAGE, table) if image_first else (table, IMAGE)
    assert main(["campaign", "sample", str(d), "--at-h", "1", str(first)]) == 0
    capsys.readouterr()
    for at in ("1", "0.5"):
        assert main(["campaign", "sample", str(d), "--at-h", at, str(second)]) == 2
        err = _err_line(capsys)
        assert f"{second}: the same particles as sample 1 at 1 h, from {first}" in err, err
    assert _rows(d, "SELECT COUNT(*) FROM samples") == [(1,)]


# --- init never replaces a file of the user's -------------------------------------------------------------
def test_init_refuses_a_file_already_in_inputs(tmp_path, capsys):
    d = tmp_path / "ov"
    (d / "inputs").mkdir(parents=True)
    mine = d / "inputs" / f"controller-{RECIPE.name}"
    mine.write_text("# my notes\n", encoding="utf-8")
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE),
                 "--target", "d50_um=45", "--hours", "2", "--particles", "60"]) == 2
    err = _err_line(capsys)
    assert f"{mine}: already exists" in err
    assert mine.read_text(encoding="utf-8") == "# my notes\n"
    assert sorted(p.name for p in d.rglob("*")) == sorted(["inputs", mine.name])  # nothing written


def test_a_failed_init_keeps_a_file_made_in_inputs_meanwhile(tmp_path, capsys, monkeypatch):
    """A file that appears in inputs/ after the check is neither replaced nor removed by the undo."""
    d = tmp_path / "c"
    mine = d / "inputs" / CARD.name
    create = db.create

    def create_then_user_writes(folder, **kw):
        con = create(folder, **kw)
        mine.parent.mkdir()
        mine.write_text("mine\n", encoding="utf-8")
        return con

    monkeypatch.setattr(wf.db, "create", create_then_user_writes)
    assert main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE),
                 "--target", "d50_um=45", "--hours", "2", "--particles", "60"]) == 2
    assert f"{mine}: already exists" in _err_line(capsys)
    assert mine.read_text(encoding="utf-8") == "mine\n"
    assert not (d / db.DB_NAME).exists()


# --- the stored scale -------------------------------------------------------------------------------------
def test_um_per_px_is_stored_only_when_an_image_was_measured_with_it(tmp_path, capsys):
    """A pixel size given with tables alone was taken and silently not used (bmctl estimate refused it)."""
    d = tmp_path / "c"
    _init(d)
    capsys.readouterr()
    for flag in ("--um-per-px", "--scale-bar-um"):
        assert main(["campaign", "sample", str(d), "--at-h", "0", flag, "3", str(TABLE)]) == 2
        assert _err_line(capsys).strip() == (f"bmctl: error: {flag}: every input is a particle table (sizes in µm "
                                     "already); it applies to micrographs only")
    assert main(["campaign", "sample", str(d), "--at-h", "0", str(TABLE)]) == 0
    assert main(["campaign", "sample", str(d), "--at-h", "0", "--um-per-px", "1.5", str(IMAGE)]) == 0
    assert _rows(d, "SELECT id, um_per_px FROM samples ORDER BY id") == [(1, None), (2, 1.5)]


def test_a_held_sample_a_rounding_off_its_node_is_judged_with_it(tmp_path, monkeypatch):
    """A sample held at 0.3 h until the log ends at 0.1 + 0.2 h: its node's update is checked for a
    near-degenerate filter with that sample counted (it was matched to nodes by exact time)."""
    d = tmp_path / "c"
    _init(d)
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.1"]) == 0
    assert main(["campaign", "sample", str(d), "--at-h", "0.3", str(TABLE)]) == 0
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.2"]) == 0
    seen = []
    monkeypatch.setattr(wf, "band_warning", lambda est, k, n, N: seen.append((est["t_h"], k)) or [])
    c = wf.Campaign(d)
    try:
        c.band_warnings()
    finally:
        c.close()
    assert seen == [(0.1 + 0.2, 1)], seen
