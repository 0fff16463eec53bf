"""`bmctl calibrate` and `bmctl identify`: an output that is one of the run's inputs is refused before any work.

The runs are given a budget no run fits in (``--budget-cpu-h 1e-9``): every input check comes before
the work estimate, so a run the checks pass stops there with the budget's message, having written nothing.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from bmctl.calibrate.history import load_history
from bmctl.cli import main

from tests.calibrate.test_calibrate import SAMPLES, SEGMENTS
from tests.conftest import card_path

LAB = card_path("alni-1to1-300rpm-lab")
NO_WORK = ("--workers", "0", "--budget-cpu-h", "1e-9")


def _table(path, seed=0, n=20):
    rng = np.random.default_rng(seed)
    s, r = rng.lognormal(np.log(40), 0.3, n), rng.uniform(0, 0.4, n)
    path.write_text("s_um,r\n" + "".join(f"{a:.4f},{b:.4f}\n" for a, b in zip(s, r)), encoding="utf-8")


def _folder(tmp_path):
    """A folder with the lab card (and its coefficients) as ``lab.toml`` and two sample tables."""
    shutil.copy(LAB, tmp_path / "lab.toml")
    shutil.copy(LAB.with_name(LAB.stem + ".moments.toml"), tmp_path / "lab.moments.toml")
    _table(tmp_path / "t1.csv")
    _table(tmp_path / "t2.csv", seed=1)
    return tmp_path


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


def _error(capsys) -> str:
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith("bmctl: error:") and "Traceback" not in err, err
    return lines[-1]


def test_a_history_where_the_calibrated_card_goes_is_refused(tmp_path, capsys):
    """--out the history's own folder, the history named <card>-calibrated.toml: the calibration
    would have replaced the history with the calibrated card."""
    d = _folder(tmp_path)
    hist = d / "lab-calibrated.toml"
    hist.write_text(SEGMENTS + SAMPLES, encoding="utf-8")
    before = _snapshot(d)
    rc = main(["calibrate", str(d / "lab.toml"), str(hist), "--out", str(d), *NO_WORK])
    line = _error(capsys)
    assert rc == 2 and "--out" in line and "lab-calibrated.toml" in line and "input" in line, line
    assert _snapshot(d) == before


def test_a_schedule_file_where_the_coefficients_go_is_refused(tmp_path, capsys):
    """The history's schedule file is where the calibrated card's moment coefficients would be written."""
    d = _folder(tmp_path)
    (d / "lab-calibrated.moments.toml").write_text(SEGMENTS, encoding="utf-8")
    hist = d / "hist.toml"
    hist.write_text('schedule = "lab-calibrated.moments.toml"\n' + SAMPLES, encoding="utf-8")
    assert load_history(hist).schedule == str(d / "lab-calibrated.moments.toml")
    before = _snapshot(d)
    rc = main(["calibrate", str(d / "lab.toml"), str(hist), "--out", str(d), *NO_WORK])
    line = _error(capsys)
    assert rc == 2 and "lab-calibrated.moments.toml" in line and "input" in line, line
    assert _snapshot(d) == before


def test_a_sample_where_a_figure_goes_is_refused(tmp_path, capsys):
    """A sample table named as the history's figure (histograms-<name>.png) in --out."""
    d = _folder(tmp_path)
    shutil.copy(d / "t2.csv", d / "histograms-run.png")
    hist = d / "hist.toml"
    hist.write_text('name = "run"\n' + SEGMENTS + SAMPLES.replace('"t2.csv"', '"histograms-run.png"'),
                    encoding="utf-8")
    rc = main(["calibrate", str(d / "lab.toml"), str(hist), "--out", str(d), *NO_WORK])
    line = _error(capsys)
    assert rc == 2 and "histograms-run.png" in line and "input" in line, line


def test_outputs_beside_the_inputs_that_are_none_of_them_pass(tmp_path, capsys):
    """--out the inputs' own folder, no output named as an input: the checks pass (the budget stops it)."""
    d = _folder(tmp_path)
    (d / "hist.toml").write_text(SEGMENTS + SAMPLES, encoding="utf-8")
    rc = main(["calibrate", str(d / "lab.toml"), str(d / "hist.toml"), "--out", str(d), *NO_WORK])
    line = _error(capsys)
    assert rc == 2 and "over the budget" in line, line
    assert load_history(d / "hist.toml").schedule is None


@pytest.mark.parametrize("how", ["same", "symbolic link"])
def test_identify_out_onto_the_card_is_refused(tmp_path, capsys, how):
    """`bmctl identify card.toml --out card.toml` wrote the coefficients over the card itself (after the
    whole identification), even though --out is checked before the work; now refused at once."""
    d = _folder(tmp_path)
    card = d / "lab.toml"
    out = card
    if how == "symbolic link":
        out = d / "link.toml"
        out.symlink_to(card)
    before = card.read_bytes()
    rc = main(["identify", str(card), "--out", str(out), "--quick", "--quiet", "--budget-cpu-h", "1e-9"])
    line = _error(capsys)
    assert rc == 2 and "--out" in line and "model card" in line, line
    assert card.read_bytes() == before


def test_identify_out_onto_a_coefficient_file_passes(tmp_path, capsys):
    """Replacing a coefficient file (the default output) is what identify does: the checks pass."""
    d = _folder(tmp_path)
    rc = main(["identify", str(d / "lab.toml"), "--out", str(d / "lab.moments.toml"), "--quick", "--quiet",
               "--budget-cpu-h", "1e-9"])
    line = _error(capsys)
    assert rc == 2 and "over the budget" in line, line


@pytest.mark.parametrize("second", ['"t1.csv"', '"./t1.csv"', '"hard.csv"'])
def test_one_table_at_two_sample_times_is_refused(tmp_path, capsys, second):
    """Both samples of a history naming one table (by its name, another spelling or a hard link) were
    fitted as two measurements at two times, its particles counted twice; now one line naming the field."""
    import os

    d = _folder(tmp_path)
    os.link(d / "t1.csv", d / "hard.csv")
    hist = d / "hist.toml"
    hist.write_text(SEGMENTS + SAMPLES.replace('"t2.csv"', second), encoding="utf-8")
    rc = main(["calibrate", str(d / "lab.toml"), str(hist), "--out", str(d / "out"), *NO_WORK])
    line = _error(capsys)
    assert rc == 2 and "hist.toml: sample[1].table" in line and "sample[0]" in line, line
    assert not (d / "out").exists()


def test_a_history_given_twice_through_a_hard_link_is_refused(tmp_path):
    import os

    from bmctl.commands.calibrate import refuse_same_file
    from bmctl.errors import InputError

    a = tmp_path / "h.toml"
    a.write_text("x = 1\n", encoding="utf-8")
    os.link(a, tmp_path / "h2.toml")
    refuse_same_file([str(a), str(tmp_path / "other.toml")])  # two files: fine
    with pytest.raises(InputError, match="given twice"):
        refuse_same_file([str(a), str(tmp_path / "h2.toml")])
