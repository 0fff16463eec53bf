"""What a campaign makes of the inputs of its samples: an image or table counted twice (the same
bytes under two names, or part of an earlier sample) is refused, a version-1 campaign (written
before inputs were hashed) is read and upgraded, a one-particle sample says why it reads no
spread, the report's sample std is the one with n - 1, and a filter that a few particles left
nearly degenerate is warned of."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import warnings
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.campaign.html_report import sample_statistics
from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
MPC = ROOT / "controllers" / "mpc-default.toml"
SAMPLES = ROOT / "examples" / "samples"


def _table(seed: int, n: int = 60) -> ParticleTable:
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(45.0), 0.45, n), rng.uniform(0.0, 0.12, n))


def _counts(d) -> dict:
    con = sqlite3.connect(str(Path(d) / db.DB_NAME))
    try:
        have = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        return {t: con.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0]
                for t in ("samples", "particles", "estimator_states", "sample_inputs") if t in have}
    finally:
        con.close()


def _err_lines(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """A campaign logged to 1 h (recipe, 100 filter particles)."""
    d = tmp_path_factory.mktemp("logged") / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, 300.0, 1.0)
    return d


def _copy(logged, tmp_path) -> Path:
    """A copy of the ``logged`` campaign to change in one test."""
    d = tmp_path / "c"
    shutil.copytree(logged, d)
    return d


def _sample_files(tmp_path, *names) -> tuple[Path, ...]:
    """Copies of the example samples ``names`` as a.csv, b.csv, ... in ``tmp_path``."""
    out = tuple(tmp_path / f"{chr(ord('a') + i)}.csv" for i in range(len(names)))
    for name, path in zip(names, out):
        shutil.copyfile(SAMPLES / name, path)
    return out


# --- the same bytes under two names ---------------------------------------------------------------
def test_one_table_under_two_names_in_one_command_is_refused_naming_both(logged, tmp_path, capsys):
    d = _copy(logged, tmp_path)
    a, b = _sample_files(tmp_path, "lab-300rpm-0p5h.csv", "lab-300rpm-0p5h.csv")
    os.link(a, tmp_path / "hard.csv")  # the same file by a second name (another path, not a symlink)
    before = _counts(d)
    for pair in ((a, b), (a, tmp_path / "hard.csv")):
        other = SAMPLES / "lab-300rpm-1h.csv"
        assert main(["campaign", "sample", str(d), "--at-h", "0.5", str(other), *map(str, pair)]) == 2
        err = _err_lines(capsys)
        assert len(err) == 1 and str(pair[1]) in err[0] and str(pair[0]) in err[0] and "the same bytes" in err[0], err
    assert _counts(d) == before  # nothing written
    # tables given in memory: the same columns twice
    with pytest.raises(InputError, match=r"table 2 \(in memory\): the same columns as table 1 \(in memory\)"):
        cp.sample(d, 0.5, [_table(1), _table(1)])
    assert _counts(d) == before


def test_a_table_of_an_earlier_larger_sample_is_refused_naming_both(logged, tmp_path, capsys):
    """A table that was one of the inputs of a stored sample, entered again under another name (or
    again as a table in memory), would count its particles twice."""
    d = _copy(logged, tmp_path)
    a, b = _sample_files(tmp_path, "lab-300rpm-0p5h.csv", "lab-300rpm-1h.csv")
    again = tmp_path / "again.csv"
    assert main(["campaign", "sample", str(d), "--at-h", "0.5", str(a), str(b)]) == 0
    shutil.copyfile(b, again)
    capsys.readouterr()
    before = _counts(d)
    for at in ("0.5", "1"):
        assert main(["campaign", "sample", str(d), "--at-h", at, str(again)]) == 2
        err = _err_lines(capsys)
        assert len(err) == 1 and str(again) in err[0] and str(b) in err[0], err
        assert "entered in sample 1 at 0.5 h" in err[0]
    assert _counts(d) == before and before["sample_inputs"] == 2  # nothing written; the two inputs' hashes
    cp.sample(d, 1.0, [_table(1), _table(2)])
    with pytest.raises(InputError, match=r"table 1 \(in memory\): the same columns as \(table\), entered in sample 2 "
                                         r"at 1 h"):
        cp.sample(d, 1.0, [_table(2)])
    assert cp.status(d)["counts"]["samples"] == 2


# --- a campaign written before the inputs were hashed (schema version 1) ------------------------------
def _as_version_1(d: Path) -> None:
    """The database as a bmctl before ``sample_inputs`` wrote it: no such table, version 1."""
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute("DROP INDEX IF EXISTS sample_inputs_by_sha256")
    con.execute("DROP TABLE IF EXISTS sample_inputs")
    con.execute("UPDATE schema_version SET version = 1")
    con.commit()
    con.close()


def _version(d: Path) -> int:
    con = sqlite3.connect(str(d / db.DB_NAME))
    try:
        return con.execute("SELECT version FROM schema_version").fetchone()[0]
    finally:
        con.close()


def test_a_version_1_campaign_is_read_upgraded_and_its_samples_matched_by_particles(logged, tmp_path, capsys):
    d = _copy(logged, tmp_path)
    a, b = _sample_files(tmp_path, "lab-300rpm-0p5h.csv", "lab-300rpm-1h.csv")
    cp.sample(d, 0.5, [a, b])
    _as_version_1(d)
    # the readers read it as it is, the verbs that do not sample leave it at version 1
    assert main(["campaign", "status", str(d)]) == 0
    assert main(["campaign", "report", str(d), "--out", str(tmp_path / "r.html")]) == 0
    cp.advise(d)
    assert _version(d) == 1 and "sample_inputs" not in _counts(d)
    # its stored sample has no input hashes: a part of it is found by its particles, and the refusal
    # leaves the campaign as it was (version 1 included)
    capsys.readouterr()
    assert main(["campaign", "sample", str(d), "--at-h", "1", str(b)]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and str(b) in err[0] and "the same particles as part of sample 1 at 0.5 h" in err[0], err
    assert _version(d) == 1 and _counts(d)["samples"] == 1
    # a new sample upgrades it: its inputs are hashed from then on
    assert main(["campaign", "sample", str(d), "--at-h", "1", str(SAMPLES / "lab-300rpm-2h.csv")]) == 0
    assert _version(d) == db.SCHEMA_VERSION == 2 and _counts(d)["sample_inputs"] == 1
    assert main(["campaign", "sample", str(d), "--at-h", "1", str(a)]) == 2  # the old sample is still matched
    assert "part of sample 1" in _err_lines(capsys)[0]
    assert main(["campaign", "status", str(d)]) == 0


@pytest.mark.parametrize("damage, named", [
    ("UPDATE sample_inputs SET sample_id = 99", "sample_inputs row 1: sample_id 99 is no sample"),
    ("UPDATE sample_inputs SET sha256 = X'00'", "sample_inputs row 1: sha256"),
    ("DROP TABLE sample_inputs", "table sample_inputs missing"),
    ("UPDATE schema_version SET version = 3", "schema version 3, this bmctl reads 1 and 2"),
])
def test_a_damaged_input_hash_is_refused_in_one_line(logged, tmp_path, capsys, damage, named):
    d = _copy(logged, tmp_path)
    cp.sample(d, 0.5, [SAMPLES / "lab-300rpm-0p5h.csv"])
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute(damage)
    con.commit()
    con.close()
    assert main(["campaign", "status", str(d)]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and db.DB_NAME in err[0] and named in err[0], err


# --- a sample of one particle ---------------------------------------------------------------------------
def test_a_one_particle_sample_says_why_the_sampling_hint_is_missing(tmp_path, capsys):
    d = tmp_path / "c"
    cp.init(d, CARD, MPC, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, 300.0, 0.5)
    (tmp_path / "one.csv").write_text("s_um,r\n41.5,0.05\n", encoding="utf-8")
    assert main(["campaign", "sample", str(d), "--at-h", "0.5", str(tmp_path / "one.csv")]) == 0
    capsys.readouterr()
    assert main(["campaign", "advise", str(d), "--json"]) == 0
    a = json.loads(capsys.readouterr().out)
    assert a["sampling"] is None
    why = [n for n in a["notes"] if "holds 1 particle" in n]
    assert len(why) == 1 and "too few to estimate the spread of sizes" in why[0] and "at 0.5 h" in why[0]
    assert main(["campaign", "advise", str(d)]) == 0
    assert "note: the latest sample (at 0.5 h) holds 1 particle: too few" in capsys.readouterr().out
    # two more particles at that time read a spread: the hint is given for the samples pooled as the
    # filter reads them (it was the latest sample's alone), and no note
    (tmp_path / "two.csv").write_text("s_um,r\n38.0,0.05\n47.0,0.07\n", encoding="utf-8")
    cp.sample(d, 0.5, [tmp_path / "two.csv"])
    a = cp.advise(d)
    assert (a["sampling"]["particles"], a["sampling"]["samples"]) == (3, 2)
    assert not any("holds" in n for n in a["notes"])
    assert main(["campaign", "advise", str(d)]) == 0
    assert "sampling: the 2 samples at 0.5 h (3 particles together) read the mean size to" in capsys.readouterr().out


# --- the report's sample std ------------------------------------------------------------------------------
def test_the_reports_sample_std_is_with_n_minus_1_and_none_for_one_particle(logged, tmp_path):
    s, r = np.array([10.0, 20.0, 30.0]), np.array([0.1, 0.2, 0.4])
    st = sample_statistics(s, r)
    assert st["s_std_um"] == pytest.approx(np.std(s, ddof=1)) and st["r_std"] == pytest.approx(np.std(r, ddof=1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "degrees of freedom <= 0" from numpy
        one = sample_statistics(np.array([12.0]), np.array([0.1]))
    assert np.isnan(one["s_std_um"]) and np.isnan(one["r_std"]) and one["s_mean_um"] == 12.0
    d = _copy(logged, tmp_path)
    t = _table(3, n=40)
    cp.sample(d, 0.5, [t])
    cp.sample(d, 1.0, [ParticleTable.from_size_aspect([33.0], [0.05])])
    page = cp.report(d, tmp_path / "r.html").read_text(encoding="utf-8")
    assert f"<td>{np.std(t.s_um, ddof=1):.4g}</td>" in page
    assert f"<td>{np.std(t.s_um):.4g}</td>" not in page
    assert "<td>n/a (1 particle)</td>" in page
    assert "standard deviation with n &minus; 1" in page


# --- a filter left nearly degenerate by two small samples at one time --------------------------------------
def _small(sizes, r0):
    return ParticleTable.from_size_aspect(np.array(sizes, float), np.linspace(0.03, 0.09, len(sizes)) + r0)


def test_two_small_samples_at_one_time_that_leave_the_filter_degenerate_are_warned_of(logged, tmp_path, capsys):
    """Two samples of three particles at 0.5 h, read as one: the filter's update leaves its weight
    on a few of its 100 particles. The numbers stay the filter's; sample, advise and the report say it."""
    d = _copy(logged, tmp_path)
    cp.sample(d, 0.5, [_small([50.0, 51.0, 52.0], 0.0)])
    assert cp.status(d)["estimate"]["t_h"] == 1.0
    first = cp.advise(d)
    with cp.Campaign(d) as c:
        ess_one = [e["ess"] for t, e in c.estimates() if t == 0.5][0]
    assert not any("degenerate" in w for w in first["warnings"])
    capsys.readouterr()
    more = _small([50.5, 51.5, 52.5], 0.005)
    (tmp_path / "more.csv").write_text("s_um,r\n" + "".join(f"{float(s)!r},{float(r)!r}\n"
                                                             for s, r in zip(more.s_um, more.r)), encoding="utf-8")
    assert main(["campaign", "sample", str(d), "--at-h", "0.5", str(tmp_path / "more.csv")]) == 0
    err = capsys.readouterr().err
    assert ("bmctl: warning: filter nearly degenerate at 0.5 h: the update by 2 samples (6 particles, read as one)"
            in err)
    from bmctl.campaign.advice import ESS_MIN

    with cp.Campaign(d) as c:
        ess = [e["ess"] for t, e in c.estimates() if t == 0.5][0]
    assert ess < ESS_MIN <= ess_one  # one small sample: not warned; the two together: warned
    assert main(["campaign", "advise", str(d)]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("warning: filter nearly degenerate at 0.5 h")]
    assert len(line) == 1 and f"about {ess:.1f} of its 100 particles" in line[0]
    a = cp.advise(d)
    assert any(w.startswith("filter nearly degenerate at 0.5 h") for w in a["warnings"])
    page = cp.report(d, tmp_path / "r.html").read_text(encoding="utf-8")
    warned = page.split("<h2>Warnings</h2>")[1].split("<h2>")[0]
    assert "filter nearly degenerate at 0.5 h" in warned


def test_samples_of_a_usual_size_give_no_filter_warning(logged, tmp_path):
    d = _copy(logged, tmp_path)
    cp.sample(d, 0.5, [SAMPLES / "lab-300rpm-0p5h.csv"])
    cp.sample(d, 1.0, [SAMPLES / "lab-300rpm-1h.csv"])
    a = cp.advise(d)
    assert not any("degenerate" in w for w in a["warnings"])
    assert "degenerate" not in cp.report(d, tmp_path / "r.html").read_text(encoding="utf-8")
