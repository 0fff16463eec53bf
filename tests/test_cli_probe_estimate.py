"""`bmctl estimate`: an output onto one of the run's inputs, and a sample file given twice, are refused."""

from __future__ import annotations

import os

import numpy as np
import pytest

from bmctl.cli import main

from tests.conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


def _table(path, seed=0, n=60):
    rng = np.random.default_rng(seed)
    s, r = rng.uniform(30, 90, n), rng.uniform(0.05, 0.4, n)
    path.write_text("s_um,r\n" + "".join(f"{a:.3f},{b:.4f}\n" for a, b in zip(s, r)), encoding="utf-8")


def _estimate(*args):
    return main(["estimate", LAB, "--particles", "100", "--no-progress", *map(str, args)])


def _one_error_line(capsys) -> str:
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bmctl: error:"), err
    assert "Traceback" not in err and not out.strip(), (out, err)
    return lines[0]


@pytest.mark.parametrize("link", [None, "hard", "symbolic"])
def test_out_onto_a_sample_table_is_refused_and_the_table_kept(tmp_path, capsys, link):
    """--out naming the sample table itself (or a hard or symbolic link to it) replaced the measured
    particles by the estimate table, exit 0; now refused in one line, the table untouched, nothing written."""
    table = tmp_path / "t1.csv"
    _table(table)
    before = table.read_bytes()
    out = table
    if link == "hard":
        out = tmp_path / "hard.csv"
        os.link(table, out)
    elif link == "symbolic":
        out = tmp_path / "sym.csv"
        out.symlink_to(table)
    rc = _estimate("--samples", table, "--times", "1", "--out", out)
    line = _one_error_line(capsys)
    assert rc == 2
    assert "--out" in line and "input" in line, line
    assert table.read_bytes() == before
    assert not (tmp_path / "t1.png").exists() and sorted(p.name for p in tmp_path.iterdir()) == \
        sorted(["t1.csv"] + ([out.name] if link else []))


def test_out_whose_figure_is_a_sample_micrograph_is_refused(tmp_path, capsys):
    """The figure goes beside --out as <name>.png: with micrographs it would replace the sample image
    of the same name. Refused before any image is measured."""
    image = tmp_path / "m.png"
    image.write_bytes(b"not looked at: refused before it is read")
    rc = _estimate("--samples", image, "--times", "1", "--um-per-px", "1", "--out", tmp_path / "m.csv")
    line = _one_error_line(capsys)
    assert rc == 2 and "--out" in line and "m.png" in line, line
    assert image.read_bytes() == b"not looked at: refused before it is read"
    assert not (tmp_path / "m.csv").exists()


@pytest.mark.parametrize("how", ["same", "folder and file", "hard link"])
def test_a_sample_file_given_twice_is_refused(tmp_path, capsys, how):
    """One table at two times was filtered as two samples (its particles counted twice), exit 0."""
    folder = tmp_path / "s"
    folder.mkdir()
    table = folder / "a.csv"
    _table(table)
    if how == "same":
        samples = [table, table]
    elif how == "folder and file":
        samples = [folder, table]
    else:
        other = tmp_path / "b.csv"
        os.link(table, other)
        samples = [table, other]
    out = tmp_path / "o" / "e.csv"
    rc = _estimate("--samples", *samples, "--times", "1,2", "--out", out)
    line = _one_error_line(capsys)
    assert rc == 2 and "--samples" in line and "twice" in line, line
    assert not out.parent.exists()


def test_distinct_samples_and_outputs_still_run(tmp_path, capsys):
    """Two tables and an --out beside them (none of them an input): the run goes on as before."""
    for k in (1, 2):
        _table(tmp_path / f"t{k}.csv", seed=k)
    rc = _estimate("--samples", tmp_path / "t1.csv", tmp_path / "t2.csv", "--times", "1,2", "--out",
                   tmp_path / "e.csv")
    assert rc == 0, capsys.readouterr().err
    assert (tmp_path / "e.csv").is_file() and (tmp_path / "e.png").is_file()


def test_a_pixel_size_with_tables_only_is_refused(tmp_path, capsys):
    """--um-per-px with particle tables only was ignored without a word (their sizes are in µm)."""
    table = tmp_path / "t1.csv"
    _table(table)
    rc = _estimate("--samples", table, "--times", "1", "--um-per-px", "0.5", "--out", tmp_path / "e.csv")
    line = _one_error_line(capsys)
    assert rc == 2 and "--um-per-px" in line and "micrographs only" in line, line
    assert not (tmp_path / "e.csv").exists()
