"""The 6-s phase and the 1000-h batch, held wherever a schedule comes in.

A calibration history's inline ``[[segment]]`` and ``bmctl campaign log --milling`` took a milling
share that left a milling or rest phase under 6 s (a schedule file refused it), and ``bmctl
simulate`` / ``bmctl whatif`` ran a schedule whose segments add up to more than the longest batch
(bmctl.limits.HOURS_MAX). Each is refused with exit 2 and one line naming the file or flag and the
field, before anything is written.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.calibrate.history import load_history
from bmctl.cli import main
from bmctl.schedule import Schedule

from tests.conftest import ROOT, card_path

LAB = card_path("alni-1to1-300rpm-lab")
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


def _one_error_line(capsys, argv) -> str:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    return lines[0]


def _files(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# --- calibration histories -----------------------------------------------------------------------

def _history(folder: Path, milling: str) -> Path:
    for k in (1, 2):
        rng = np.random.default_rng(k)
        s, r = rng.lognormal(np.log(40.0), 0.3, 20), rng.uniform(0.0, 0.4, 20)
        (folder / f"t{k}.csv").write_text("s_um,r\n" + "".join(f"{a:.4f},{b:.4f}\n" for a, b in zip(s, r)), encoding="utf-8")
    p = folder / "hist.toml"
    p.write_text(f"[[segment]]\nhours = 3\nrpm = 300\nmilling = {milling}\n"
                 '[[sample]]\nt_h = 1.0\ntable = "t1.csv"\n[[sample]]\nt_h = 2.0\ntable = "t2.csv"\n', encoding="utf-8")
    return p


@pytest.mark.parametrize("milling,phase", [("0.0001", "mills 1.1 s"), ("0.99999", "rests 0.11 s")])
def test_calibrate_refuses_a_history_share_leaving_a_phase_under_six_seconds(tmp_path, capsys, monkeypatch,
                                                                             milling, phase):
    """0.0001 of 3 h mills 1.1 s, 0.99999 rests 0.11 s: a schedule file refused both, a history took them."""
    import bmctl.calibrate.run as run

    monkeypatch.setattr(run, "run_calibration", lambda *a, **k: pytest.fail("the history was accepted"))
    hist = _history(tmp_path, milling)
    before = _files(tmp_path)
    line = _one_error_line(capsys, ["calibrate", LAB, hist, "--workers", "0", "--out", tmp_path / "out"])
    assert line.startswith(f"bmctl: error: {hist}: segment[0].milling: {phase}"), line
    assert "6 s" in line
    assert not (tmp_path / "out").exists() and _files(tmp_path) == before


@pytest.mark.parametrize("milling", ["0.5", "0.0005556", "1", "0"])
def test_history_shares_leaving_six_seconds_or_no_second_phase_are_kept(tmp_path, milling):
    """0.0005556 of 3 h mills 6.0 s, the shortest phase kept; 0 and 1 leave a single phase."""
    h = load_history(_history(tmp_path, milling))
    assert h.segments == [(3.0, 300.0, float(milling))]


# --- campaign log ----------------------------------------------------------------------------------

@pytest.mark.parametrize("milling,phase", [("0.001", "mills 1.8 s"), ("0.99999", "rests 0.018 s")])
def test_campaign_log_refuses_a_share_leaving_a_phase_under_six_seconds(tmp_path, capsys, milling, phase):
    """--milling 0.001 of --hours 0.5 mills 1.8 s (0.99999 rests 0.018 s) and was logged as milling."""
    d = tmp_path / "c"
    cp.init(d, LAB, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    before = _files(d)
    line = _one_error_line(capsys, ["campaign", "log", d, "--rpm", "300", "--hours", "0.5", "--milling", milling])
    assert line.startswith(f"bmctl: error: --milling {milling} of --hours 0.5: {phase}"), line
    assert "6 s" in line
    assert _files(d) == before and cp.status(d)["counts"]["actions"] == 0


def test_campaign_log_takes_a_share_of_one_rounded_and_a_six_second_phase(tmp_path, capsys):
    """A short last interval's share of 1, computed (bmctl.loop.interval_share), may come out
    0.99999999999999: its rest of picoseconds is rounding, not a phase (``trial --campaign`` logs it).
    0.00333334 of 0.5 h mills 6.0 s, the shortest phase kept."""
    d = tmp_path / "c"
    cp.init(d, LAB, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.2", "--milling", "0.99999999999999"]) == 0
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5", "--milling", "0.00333334"]) == 0
    assert cp.status(d)["counts"]["actions"] == 2, capsys.readouterr().err


# --- a schedule longer than the longest batch -----------------------------------------------------

def _long_schedule(tmp_path: Path) -> Path:
    p = tmp_path / "long.toml"
    p.write_text("[[segment]]\nhours = 600\nrpm = 300\n[[segment]]\nhours = 600\nrpm = 0\n", encoding="utf-8")
    return p


@pytest.mark.parametrize("verb", ["simulate", "whatif"])
def test_a_schedule_longer_than_the_longest_batch_is_refused(tmp_path, capsys, monkeypatch, verb):
    """Two segments of 600 h, each within 1000 h, add up to 1200 h: both commands ran them."""
    import bmctl.simulate
    import bmctl.whatif

    monkeypatch.setattr(bmctl.simulate, "simulate", lambda *a, **k: pytest.fail("the schedule was run"))
    monkeypatch.setattr(bmctl.whatif, "run_schedule_ensemble", lambda *a, **k: pytest.fail("the schedule was run"))
    sched = _long_schedule(tmp_path)
    argv = (["simulate", LAB, "--schedule", sched, "--particles", "100"] if verb == "simulate"
            else ["whatif", LAB, sched, "--seeds", "1", "--particles", "100"])
    line = _one_error_line(capsys, argv + ["--out", tmp_path / "o"])
    assert line.startswith(f"bmctl: error: {sched}: segment: "), line
    assert "1200 h" in line and "1000 h" in line, line
    assert not (tmp_path / "o").exists()


def test_a_schedule_of_exactly_the_longest_batch_is_kept(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[[segment]]\nhours = 600\nrpm = 300\n[[segment]]\nhours = 400\nrpm = 0\n", encoding="utf-8")
    assert Schedule.load(p).hours == 1000.0
