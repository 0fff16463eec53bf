"""``bmctl trial --campaign``: a trial driven through the campaign verbs gives the plain trial's
trajectory.csv, leaves a campaign that ``bmctl campaign`` opens, and refuses what it cannot do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bmctl.cli import main

from .scenarios import lqr_scenario


def _read(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and the cells as written (numbers at the CSV's precision, the solver status as text)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return lines[0].split(","), np.array([ln.split(",") for ln in lines[1:]])


@pytest.mark.slow
def test_trial_campaign_cli_gives_the_plain_trajectory_and_a_campaign(tmp_path, capsys):
    sc = lqr_scenario(tmp_path / "scenario.toml")
    plain, camp = tmp_path / "plain", tmp_path / "camp"
    assert main(["trial", str(sc), "--seed", "5", "--out", str(plain), "--no-progress"]) == 0
    assert main(["trial", str(sc), "--seed", "5", "--out", str(camp), "--no-progress", "--campaign"]) == 0
    h1, a = _read(plain / "trajectory.csv")
    h2, b = _read(camp / "trajectory.csv")
    assert h1 == h2 and a.shape == b.shape == (4, len(h1))
    same = [i for i, k in enumerate(h1) if k != "solve_ms"]  # wall time of the solve differs run to run
    np.testing.assert_array_equal(a[:, same], b[:, same])
    assert np.isfinite(a[:, same[:-3]].astype(float)).all()  # a real trajectory, not empty cells
    s1 = json.loads((plain / "summary.json").read_text(encoding="utf-8"))
    s2 = json.loads((camp / "summary.json").read_text(encoding="utf-8"))
    for k in ("final_true", "final_estimate", "final_error", "max_temperature_c", "temperature_violations",
              "energy_kj", "fallbacks", "solver_failures", "steps", "batch_h"):
        assert s1[k] == s2[k], k
    assert (camp / "trial.png").stat().st_size > 10_000
    # the campaign it leaves is a campaign: status and report open it
    capsys.readouterr()
    assert main(["campaign", "status", str(camp / "campaign")]) == 0
    assert "2" in capsys.readouterr().out
    assert main(["campaign", "report", str(camp / "campaign")]) == 0
    assert (camp / "campaign" / "report.html").stat().st_size > 10_000
    from bmctl import campaign as cp

    st = cp.status(camp / "campaign")
    assert st["clock_h"] == 2.0 and st["counts"]["actions"] == 4 and st["counts"]["samples"] == 2
    assert st["counts"]["decisions"] == 4 and st["deviations"] == []
    # resuming is refused with one line, for the folder and for the flag
    assert main(["trial", str(sc), "--seed", "5", "--resume", str(camp), "--no-progress"]) == 2
    assert main(["trial", str(sc), "--seed", "5", "--out", str(camp), "--no-progress", "--campaign"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "does not resume" in err and "already holds" in err


def test_trial_campaign_refusals_are_one_line(tmp_path, capsys):
    sc = lqr_scenario(tmp_path / "scenario.toml")
    assert main(["trial", str(sc), "--campaign", "--resume", str(tmp_path / "x"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--campaign does not resume" in err
    ukf = lqr_scenario(tmp_path / "ukf.toml", 'kind = "ukf"')
    ukf.write_text(ukf.read_text(encoding="utf-8").replace("[estimator]\nparticles = 100\n", "[estimator]\n"), encoding="utf-8")
    assert main(["trial", str(ukf), "--campaign", "--out", str(tmp_path / "u"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "particle filter" in err
    assert not (tmp_path / "u" / "campaign").exists()
    assert main(["trial", str(sc), "--campaign", "--seed", "x", "--no-progress"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_a_window_target_is_refused_before_anything_is_written(tmp_path, capsys):
    """A campaign steers to one value: `trial --campaign` of a window once failed inside the campaign
    with "target: d50_um: not a number ((40.0, 50.0))" after writing trial.json."""
    from bmctl.cli import main

    from .scenarios import lqr_scenario

    sc = lqr_scenario(tmp_path / "s.toml")
    sc.write_text(sc.read_text(encoding="utf-8").replace("target = { s_mean_um = 40.0 }", "target = { d50_um = [40.0, 50.0] }"), encoding="utf-8")
    assert "[40.0, 50.0]" in sc.read_text(encoding="utf-8")
    out = tmp_path / "o"
    assert main(["trial", str(sc), "--campaign", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "target.d50_um: a campaign steers to one value, not a window (e.g. d50_um = 45)" in err[0]
    assert not out.exists()


@pytest.mark.slow
def test_trial_campaign_mills_the_advised_minutes_in_a_short_last_interval(tmp_path):
    """2.2 h of 40-min cycles: the last interval is 12 min; the advice's share is of the whole
    interval, so the campaign mills and logs the advised minutes, as the plain trial does."""
    sc = lqr_scenario(tmp_path / "scenario.toml")  # the 30/10 recipe: 30 of every 40 min, 12 min left at the end
    recipe = Path(__file__).resolve().parents[2] / "controllers" / "recipe-400rpm-30-10.toml"
    text = sc.read_text(encoding="utf-8").replace("hours = 2.0", "hours = 2.2")
    sc.write_text(text[:text.index("config = ")] + f'config = "{recipe}"\n', encoding="utf-8")
    plain, camp = tmp_path / "plain", tmp_path / "camp"
    assert main(["trial", str(sc), "--seed", "5", "--out", str(plain), "--no-progress"]) == 0
    assert main(["trial", str(sc), "--seed", "5", "--out", str(camp), "--no-progress", "--campaign"]) == 0
    from bmctl import campaign as cp

    st = cp.status(camp / "campaign")
    assert st["clock_h"] == pytest.approx(2.2) and st["deviations"] == []
    h1, a = _read(plain / "trajectory.csv")
    _, b = _read(camp / "trajectory.csv")
    same = [i for i, k in enumerate(h1) if k != "solve_ms"]
    np.testing.assert_array_equal(a[:, same], b[:, same])


@pytest.mark.slow
def test_a_remainder_under_a_second_ends_the_last_interval(tmp_path):
    """interval_h = 0.3333333 over 1 h leaves 0.36 ms: it was a fourth interval that the campaign's log
    refused ("--hours: must be >= 0.000277778"), so ``trial --campaign`` failed at the batch end; now
    it ends the third, in the plain trial and through the campaign alike."""
    lqr = Path(__file__).resolve().parents[2] / "controllers" / "lqr-baseline.toml"
    ctrl = tmp_path / "lqr-20min.toml"
    ctrl.write_text(lqr.read_text(encoding="utf-8").replace("interval_h = 0.5", "interval_h = 0.3333333"), encoding="utf-8")
    sc = lqr_scenario(tmp_path / "scenario.toml")
    text = sc.read_text(encoding="utf-8").replace("hours = 2.0", "hours = 1.0")
    sc.write_text(text[:text.index("config = ")] + f'config = "{ctrl}"\n', encoding="utf-8")
    plain, camp = tmp_path / "plain", tmp_path / "camp"
    assert main(["trial", str(sc), "--seed", "5", "--out", str(plain), "--no-progress"]) == 0
    assert main(["trial", str(sc), "--seed", "5", "--out", str(camp), "--no-progress", "--campaign"]) == 0
    s1 = json.loads((plain / "summary.json").read_text(encoding="utf-8"))
    s2 = json.loads((camp / "summary.json").read_text(encoding="utf-8"))
    assert s1["steps"] == s2["steps"] == 3
    from bmctl import campaign as cp

    assert cp.status(camp / "campaign")["clock_h"] == pytest.approx(1.0)
