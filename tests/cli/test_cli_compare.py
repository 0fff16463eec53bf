"""`bmctl compare`: the schedule checked against the card as `simulate` and `whatif` check it (the
mill's top speed, the melting stop, the validity warnings) before any work."""

from __future__ import annotations

import pytest

from bmctl.cli import main

from ..conftest import ROOT, card_path

LAB = card_path("alni-1to1-300rpm-lab")
SAMPLE = str(ROOT / "examples" / "samples" / "lab-300rpm-2h.csv")


def _schedule(tmp_path, hours, rpm, name="s.toml"):
    p = tmp_path / name
    p.write_text(f"[[segment]]\nhours = {hours}\nrpm = {rpm}\n", encoding="utf-8")
    return str(p)


def _card(tmp_path, old, new):
    text = LAB.read_text(encoding="utf-8")
    assert old in text
    p = tmp_path / "card.toml"
    p.write_text(text.replace(old, new), encoding="utf-8")
    return str(p)


def _compare(capsys, card, sched, at_h, out):
    rc = main(["compare", SAMPLE, "--model", str(card), "--schedule", sched, "--at-h", str(at_h),
               "--particles", "200", "--out", str(out)])
    _, err = capsys.readouterr()
    return rc, err


def _refused(rc, err, out):
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    assert "Traceback" not in err and not out.exists()
    return lines[0]


def test_compare_refuses_a_schedule_that_melts_the_powder(tmp_path, capsys):
    """A vial of 100 J/K at 600 rpm for 2 h reaches 1322 °C: simulate and whatif refuse it, compare ran it."""
    card = _card(tmp_path, "heat_capacity_J_per_K = ", "heat_capacity_J_per_K = 100 # ")
    sched = _schedule(tmp_path, 2, 600)
    out = tmp_path / "o"
    line = _refused(*_compare(capsys, card, sched, 2, out), out)
    assert f"{sched}: the vial would reach 1322 °C at 2 h, above 660.3 °C" in line, line
    assert main(["simulate", card, "--schedule", sched, "--particles", "200", "--out", str(tmp_path / "s"),
                 "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == line  # the same line as simulate's


def test_compare_checks_only_the_schedule_up_to_the_sample(tmp_path, capsys):
    """The plant runs the schedule cut at --at-h: a melting hour after the sample is not run."""
    card = _card(tmp_path, "heat_capacity_J_per_K = ", "heat_capacity_J_per_K = 100 # ")
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = 0.5\nrpm = 0\n[[segment]]\nhours = 2\nrpm = 600\n", encoding="utf-8")
    rc, err = _compare(capsys, card, str(sched), 0.5, tmp_path / "o")
    assert rc == 0 and "bmctl: error" not in err, err


def test_compare_warns_as_simulate_outside_the_validity_range(tmp_path, capsys):
    """3 h at 600 rpm (a steady vial of 349 °C, above a stated maximum of 300 °C): simulate warns, compare
    said nothing."""
    card = _card(tmp_path, "calibrated_temperature_max_C", "temperature_max_C = 300\ncalibrated_temperature_max_C")
    sched = _schedule(tmp_path, 3, 600)
    rc = main(["simulate", card, "--schedule", sched, "--particles", "200", "--out", str(tmp_path / "s"),
               "--no-progress"])
    warned = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("bmctl: warning: ")]
    assert rc == 0 and len(warned) == 2, warned
    rc, err = _compare(capsys, card, sched, 3, tmp_path / "o")
    assert rc == 0 and (tmp_path / "o" / "compare.json").exists(), err
    lines = err.strip().splitlines()
    assert lines == warned, err
    assert "vial temperature 349 °C at 3 h is above the card's maximum 300 °C" in lines[0]
    assert "steady vial temperature 349 °C at 600 rpm is outside" in lines[1]


def test_compare_within_the_range_warns_of_nothing(tmp_path, capsys):
    rc, err = _compare(capsys, LAB, _schedule(tmp_path, 2, 300), 2, tmp_path / "o")
    assert rc == 0 and err == "", err


@pytest.mark.parametrize("at_h", [0.5, 2])
def test_compare_names_the_schedule_segment_faster_than_the_mill(tmp_path, capsys, at_h):
    """A segment at 1500 rpm on a 600 rpm mill gave `rpm: must be in [0, 600] (got 1500)` from inside the
    plant, naming no file; whatif names the file and segment."""
    sched = tmp_path / "fast.toml"
    sched.write_text("[[segment]]\nhours = 1\nrpm = 300\n[[segment]]\nhours = 1\nrpm = 1500\n", encoding="utf-8")
    out = tmp_path / "o"
    line = _refused(*_compare(capsys, LAB, str(sched), at_h, out), out)
    assert line == f"bmctl: error: {sched}: segment[1].rpm: 1500 exceeds the mill's rpm_max 600", line


def test_compare_refuses_a_one_particle_table_before_the_plant_runs(tmp_path, capsys, monkeypatch):
    """A one-row table ran the plant (seconds) and then said "compare: need at least 2 particles on each
    side (got 1 and 20000)", naming neither the file nor which side was short."""
    import bmctl.measure.compare

    def no_plant(*_args, **_kwargs):
        raise AssertionError("the plant ran")

    monkeypatch.setattr(bmctl.measure.compare, "predicted_population", no_plant)
    one = tmp_path / "one.csv"
    one.write_text("s_um,r\n50,0.1\n", encoding="utf-8")
    out = tmp_path / "o"
    rc = main(["compare", str(one), "--model", str(LAB), "--at-h", "12", "--out", str(out)])
    line = _refused(rc, capsys.readouterr().err, out)
    assert line == f"bmctl: error: {one}: need at least 2 particles (got 1)"
