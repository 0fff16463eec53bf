"""`bmctl simulate`: outputs, reproducibility, and one-line errors on bad input."""

import csv
import shutil

import numpy as np
import pytest

from bmctl.cli import main

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
HEADER = ("t_h,s_mean_um,s_std_um,s_mode_um,r_mean,r_std,r_mode,temperature_c,bond_events,fracture_events,"
          "d10_um,d50_um,d90_um,span,s_mean_area_um,s_mode_area_um")


def run(args, capsys):
    rc = main(args)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.slow
def test_simulate_writes_outputs_and_same_seed_is_identical(tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for d, seed in ((a, 7), (b, 7), (c, 8)):
        rc, _, err = run(["simulate", LAB, "--hours", "3", "--particles", "1500", "--seed", str(seed), "--out", str(d),
                          "--no-progress"], capsys)
        assert rc == 0, err
    text = (a / "moments.csv").read_text(encoding="utf-8")
    assert text.splitlines()[0] == HEADER
    rows = list(csv.DictReader(text.splitlines()))
    assert [float(r["t_h"]) for r in rows] == [0, 1, 2, 3]
    assert int(rows[0]["bond_events"]) == 0 and int(rows[1]["bond_events"]) > 0
    assert text == (b / "moments.csv").read_text(encoding="utf-8")
    assert text != (c / "moments.csv").read_text(encoding="utf-8")
    pop = np.load(a / "population.npz")
    assert pop["p"].shape == (4, pop["s_edges_um"].size - 1, pop["r_edges"].size - 1)
    np.testing.assert_allclose(pop["p"].sum(axis=(1, 2)), 1.0, rtol=1e-5)
    assert np.diff(pop["s_edges_um"])[0] == pytest.approx(1.0) and np.diff(pop["r_edges"])[0] == pytest.approx(0.01)
    for png in ("size_pdf.png", "aspect_pdf.png", "moments.png", "size_heatmap.png"):
        assert (a / png).read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_schedule_file_with_rest(tmp_path, capsys):
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = 1\nrpm = 400\n[[segment]]\nhours = 1\nrpm = 0\n", encoding="utf-8")
    rc, _, err = run(["simulate", LAB, "--schedule", str(sched), "--particles", "500", "--out", str(tmp_path / "o"),
                      "--no-progress"], capsys)
    assert rc == 0, err
    rows = list(csv.DictReader((tmp_path / "o" / "moments.csv").read_text(encoding="utf-8").splitlines()))
    assert int(rows[2]["bond_events"]) == 0 and int(rows[2]["fracture_events"]) == 0  # the rest hour
    assert float(rows[2]["temperature_c"]) < float(rows[1]["temperature_c"])


def _card_variant(tmp_path, old, new):
    text = open(LAB, encoding="utf-8").read()
    assert old in text
    p = tmp_path / "card.toml"
    p.write_text(text.replace(old, new, 1), encoding="utf-8")
    return str(p)


@pytest.mark.parametrize("case,expect", [
    ("missing", "file not found"),
    ("malformed", "malformed TOML"),
    ("unknown", "stochastic.colour: unknown field"),
    ("negative", "material.yield_stress_Pa"),
    ("nan", "stochastic.alpha"),
    ("missing_field", "stochastic.beta: required field is missing"),
])
def test_bad_card_one_line_exit2_nothing_written(tmp_path, capsys, case, expect):
    if case == "missing":
        card = str(tmp_path / "nope.toml")
    elif case == "malformed":
        card = _card_variant(tmp_path, "[stochastic]", "[stochastic")
    elif case == "unknown":
        card = _card_variant(tmp_path, "alpha = 2.1", "alpha = 2.1\ncolour = 3")
    elif case == "negative":
        card = _card_variant(tmp_path, "yield_stress_Pa = 78.7e6", "yield_stress_Pa = -78.7e6")
    elif case == "nan":
        card = _card_variant(tmp_path, "alpha = 2.1", "alpha = nan")
    else:
        card = _card_variant(tmp_path, "beta = 1.8", "")
    out = tmp_path / "out"
    rc, _, err = run(["simulate", card, "--hours", "1", "--particles", "200", "--out", str(out)], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bmctl: error:"), err
    assert expect in lines[0]
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("flags,expect", [
    (["--hours", "-2"], "--hours"), (["--hours", "nan"], "--hours"), (["--hours", "0"], "--hours"),
    (["--hours", "1_0"], "--hours: not a number"),  # float() reads "1_0" as 10
    (["--particles", "2_000"], "--particles: not an integer"),  # and int() "2_000" as 2000
    (["--particles", "3"], "--particles"), (["--seed", "x"], "--seed"), (["--rpm", "9000"], "rpm"),
    (["--bogus"], "unrecognized"),
])
def test_bad_flags(tmp_path, capsys, flags, expect):
    out = tmp_path / "out"
    rc, _, err = run(["simulate", LAB, *flags, "--out", str(out)], capsys)
    assert rc == 2 and expect in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_schedule(tmp_path, capsys):
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = -1\nrpm = 300\n", encoding="utf-8")
    rc, _, err = run(["simulate", LAB, "--schedule", str(sched), "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "segment[0].hours" in err and str(sched) in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("verb", ["simulate", "estimate"])
def test_schedule_faster_than_the_mill_names_its_segment(tmp_path, capsys, verb):
    """simulate and estimate said "s.toml: rpm 1500 exceeds ..." where compare and whatif name the segment
    ("s.toml: segment[1].rpm: ..."), as the one-line error format promises."""
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = 1\nrpm = 300\n[[segment]]\nhours = 2\nrpm = 1500\n", encoding="utf-8")
    out = tmp_path / "o"
    extra = (["--samples", str(card_path("alni-1to1-300rpm-lab").parents[1] / "examples" / "samples"), "--times",
              "0.5,1,2,4,8"] if verb == "estimate" else [])
    rc, _, err = run([verb, LAB, "--schedule", str(sched), *extra, "--out", str(out)], capsys)
    assert rc == 2 and err.strip() == f"bmctl: error: {sched}: segment[1].rpm: 1500 exceeds the mill's rpm_max 600", err
    assert not out.exists()


@pytest.mark.slow
def test_failed_rerun_keeps_previous_outputs(tmp_path, capsys):
    out = tmp_path / "o"
    rc, _, _ = run(["simulate", LAB, "--hours", "1", "--particles", "300", "--out", str(out), "--no-progress"], capsys)
    assert rc == 0
    before = (out / "moments.csv").read_text(encoding="utf-8")
    rc, _, _ = run(["simulate", LAB, "--hours", "-1", "--out", str(out)], capsys)
    assert rc == 2
    assert (out / "moments.csv").read_text(encoding="utf-8") == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary leftovers
    shutil.rmtree(out)


@pytest.mark.parametrize("command", [
    ["simulate", LAB], ["whatif", LAB, str(card_path("alni-1to1-300rpm-lab").parent.parent / "scenarios"
                                           / "schedule-lab-300rpm-12h.toml")],
    ["linearize", LAB], pytest.param(["verify", "--quick"], marks=pytest.mark.slow), ["identify", LAB, "--quick"],
])
def test_unwritable_out_fails_before_any_work(tmp_path, capsys, command):
    """An --out below a file (a typo, a read-only place) is reported at once: one line, exit 2, nothing made."""
    blocker = tmp_path / "afile"
    blocker.write_text("x", encoding="utf-8")
    target = blocker / ("c.toml" if command[0] == "identify" else "out")
    rc, out, err = run([*command, "--out", str(target)], capsys)
    assert rc == 2 and err.startswith("bmctl: error: --out:") and "not a folder" in err
    assert len(err.strip().splitlines()) == 1 and out == ""  # refused before the run printed anything
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_write_failure_during_output_is_one_line(tmp_path, capsys, monkeypatch):
    """An OSError while writing (disk full, permissions changed mid-run) names the file: exit 2, no traceback."""
    import bmctl.simulate as sim

    def full(*_a, **_k):
        raise OSError(28, "No space left on device", str(tmp_path / "o" / "moments.csv"))

    monkeypatch.setattr(sim, "write_outputs", full)
    rc, _, err = run(["simulate", LAB, "--hours", "0.2", "--particles", "200", "--out", str(tmp_path / "o"),
                      "--no-progress"], capsys)
    assert rc == 2 and err.strip() == f"bmctl: error: {tmp_path / 'o' / 'moments.csv'}: No space left on device"
