"""Closed-loop trials: outputs, resume after interruption, bad scenario files."""

import json
from pathlib import Path

import pytest

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.trial import run_trial, trajectory_header

from ..conftest import ROOT

SMALL = """
model = "{root}/models/alni-1to1-300rpm-lab.toml"
hours = 2
target = {{ s_mean_um = 50.0 }}
[scenario]
name = "small"
description = "two hours of MPC on a small plant"
[plant]
particles = 1000
gamma_factor = 1.3
delta_factor = 0.7
[sampling]
every_h = 1.0
particles = 200
[estimator]
particles = 300
[controller]
config = "{root}/controllers/mpc-fast.toml"
"""


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("sc")
    p = d / "small.toml"
    p.write_text(SMALL.format(root=ROOT), encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def one_step(small, tmp_path_factory):
    """A trial of ``small`` (seed 1) stopped after its first interval, as a crash would leave it."""
    out = tmp_path_factory.mktemp("one") / "o"
    assert run_trial(small, out, seed=1, max_steps=1) == {"interrupted_at_step": 1}
    return out


def _copy(folder, tmp_path):
    import shutil

    return Path(shutil.copytree(folder, tmp_path / "o"))


def _rows(path):
    return path.read_text(encoding="utf-8").splitlines()


@pytest.mark.slow
def test_trial_outputs_and_resume_identical(small, tmp_path):
    full = tmp_path / "full"
    summary = run_trial(small, full, seed=5)
    for key in ("target", "final_true", "final_error", "max_temperature_c", "temperature_violations", "energy_kj",
                "batch_h", "solver_failures", "fallbacks"):
        assert key in summary
    assert json.loads((full / "summary.json").read_text(encoding="utf-8"))["batch_h"] == pytest.approx(2.0)
    rows = _rows(full / "trajectory.csv")
    assert rows[0].split(",") == trajectory_header()
    assert len(rows) == 1 + 4  # 0.5 h intervals
    assert (full / "trial.png").read_bytes()[:4] == b"\x89PNG"
    # interrupted after 2 steps, then resumed: the same trajectory (timing columns aside)
    part = tmp_path / "part"
    assert run_trial(small, part, seed=5, max_steps=2) == {"interrupted_at_step": 2}
    assert len(_rows(part / "trajectory.csv")) == 3
    # a row written after the last checkpoint (killed between the two writes) is dropped on resume
    with open(part / "trajectory.csv", "a", encoding="utf-8") as fh:
        fh.write("garbage\n")
    assert run_trial(small, part, seed=5, resume=True, max_steps=1) == {"interrupted_at_step": 3}
    # killed mid-write of the next row: the torn row (no newline) is dropped on resume
    with open(part / "trajectory.csv", "a", encoding="utf-8") as fh:
        fh.write("3,2,300,0.5,61.")
    run_trial(small, part, seed=5, resume=True)
    strip = lambda lines: [",".join(r.split(",")[:-3]) for r in lines]  # noqa: E731 - drop ms/status/fallback
    assert strip(_rows(part / "trajectory.csv")) == strip(rows)
    assert not list(part.glob("*.pkl"))


@pytest.mark.slow
def test_checkpoint_is_plain_data(one_step):
    import numpy as np

    out = one_step
    with np.load(out / "checkpoint.npz", allow_pickle=False) as z:  # raises if any entry needs pickle
        assert all(z[k].dtype != object for k in z.files)


@pytest.mark.slow
@pytest.mark.parametrize("target,content", [
    ("checkpoint.npz", b"PK\x03\x04 not really a zip"),
    ("checkpoint.npz", None),  # truncated to half its length
    ("trial.json", b'{"scenario": "x", "se'),
])
def test_resume_refuses_damaged_files_one_line(small, one_step, tmp_path, capsys, target, content):
    out = _copy(one_step, tmp_path)
    f = out / target
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2] if content is None else content)
    capsys.readouterr()
    rc = main(["trial", str(small), "--resume", str(out), "--seed", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and target in err, err
    # with the progress bar on, a log (stderr not a terminal) gets the same one line, no bar fragment
    assert main(["trial", str(small), "--resume", str(out), "--seed", "1"]) == 2
    assert capsys.readouterr().err == err


@pytest.mark.slow
def test_resume_refuses_other_seed(small, one_step, tmp_path, capsys):
    out = _copy(one_step, tmp_path)
    capsys.readouterr()
    rc = main(["trial", str(small), "--resume", str(out), "--seed", "2", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "holds the trial with seed 1, not 2; carry it on with --seed 1" in err


@pytest.mark.parametrize("edit,expect", [
    (("hours = 2", "hours = -2"), "hours"),
    (("gamma_factor = 1.3", "gamma_factor = nan"), "plant.gamma_factor"),
    (("s_mean_um = 50.0", "s_size = 50.0"), "target.s_size"),
    (("mpc-fast.toml", "nope.toml"), "not found"),
    (("[plant]", "[plant"), "malformed TOML"),
    (("particles = 1000", "particles = 1000\ncolour = 1"), "plant.colour: unknown field"),
])
def test_bad_scenario_one_line_exit2(small, tmp_path, capsys, edit, expect):
    text = small.read_text(encoding="utf-8")
    assert edit[0] in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(edit[0], edit[1], 1), encoding="utf-8")
    out = tmp_path / "o"
    rc = main(["trial", str(bad), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and err.startswith("bmctl: error:") and expect in err, err
    assert not out.exists()


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("trial-*.toml")))
def test_shipped_scenarios_validate(name):
    from bmctl.scenario import load_scenario

    sc = load_scenario(ROOT / "scenarios" / name)
    assert sc.scenario.description and "\n" not in sc.scenario.description


@pytest.mark.slow
@pytest.mark.parametrize("extra", ["", "feed = true\n"])
def test_a_default_controller_trial_resumes_to_the_uninterrupted_trajectory(tmp_path, extra):
    """mpc-default keeps its last plan's family (text) in its state, and a run's tallies grow (a
    fallback's log, the feed sampled): a checkpoint holding them was once refused as damaged."""
    text = SMALL.format(root=ROOT).replace("mpc-fast.toml", "mpc-default.toml").replace(
        "particles = 200\n", "particles = 200\n" + extra)
    assert "mpc-default.toml" in text and (not extra or extra in text)
    sc = tmp_path / "s.toml"
    sc.write_text(text, encoding="utf-8")
    whole = run_trial(sc, tmp_path / "whole", seed=3)
    # three steps in: the planner's history holds entries a fresh loop holds none of
    assert run_trial(sc, tmp_path / "cut", seed=3, max_steps=3) == {"interrupted_at_step": 3}
    resumed = run_trial(sc, tmp_path / "cut", seed=3, resume=True)
    assert resumed["final_true"] == whole["final_true"] and resumed["final_estimate"] == whole["final_estimate"]
    rows = lambda p: [r.split(",")[:-4] for r in _rows(p / "trajectory.csv")]  # solve times aside
    assert rows(tmp_path / "cut") == rows(tmp_path / "whole")


def test_resume_refuses_a_scenario_edited_since_the_trial_began(small, tmp_path, capsys):
    """A resumed trial once ran its remaining steps under the edited file (hours, plant factors),
    splicing two trials into one trajectory."""
    import shutil

    sc = tmp_path / "s.toml"
    shutil.copy(small, sc)
    out = tmp_path / "o"
    assert run_trial(sc, out, seed=1, max_steps=1) == {"interrupted_at_step": 1}
    sc.write_text(sc.read_text(encoding="utf-8").replace("gamma_factor = 1.3", "gamma_factor = 3.0"), encoding="utf-8")
    assert main(["trial", str(sc), "--resume", str(out), "--seed", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "changed since the trial" in err[0], err


def test_a_scenario_runs_the_files_beside_it_from_any_working_directory(tmp_path, monkeypatch):
    """A relative card path is looked up next to the scenario first: a same-named file under the
    working directory once shadowed the project's card."""
    from bmctl.scenario import resolve

    proj = tmp_path / "proj"
    (proj / "scenarios").mkdir(parents=True)
    (proj / "models").mkdir()
    (proj / "models" / "c.toml").write_text("x", encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "models").mkdir(parents=True)
    (elsewhere / "models" / "c.toml").write_text("y", encoding="utf-8")
    monkeypatch.chdir(elsewhere)
    assert resolve("models/c.toml", proj / "scenarios") == proj / "models" / "c.toml"


def test_a_scenario_name_never_leads_the_default_output_out_of_out(tmp_path, monkeypatch, capsys):
    text = (ROOT / "scenarios" / "trial-lab-recipe.toml").read_text(encoding="utf-8")
    text = text.replace('"models/', f'"{ROOT}/models/').replace('"controllers/', f'"{ROOT}/controllers/')
    text = __import__("re").sub(r'(?m)^name = ".*"$', 'name = "../../../esc"', text, count=1)
    assert 'name = "../../../esc"' in text
    (tmp_path / "sub").mkdir()
    (tmp_path / "esc.toml").write_text(text, encoding="utf-8")
    monkeypatch.chdir(tmp_path / "sub")
    assert main(["trial", str(tmp_path / "esc.toml"), "--no-progress"]) == 0, capsys.readouterr().err
    made = [p.name for p in (tmp_path / "sub" / "out").iterdir()]
    assert made == ["trial-esc-seed0"], made
    assert sorted(p.name for p in tmp_path.iterdir()) == ["esc.toml", "sub"]


def test_a_scenario_ceiling_below_the_ambient_is_refused(small, tmp_path, capsys):
    sc = tmp_path / "s.toml"
    sc.write_text(small.read_text(encoding="utf-8").replace('hours = 2\n', 'hours = 2\ntemperature_max_c = 20.0\n'), encoding="utf-8")
    assert "temperature_max_c = 20.0" in sc.read_text(encoding="utf-8")
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "temperature_max_c: 20 °C is not above the card's ambient" in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("table, said", [
    ('[estimator.pf]\nadapt_rat = 0.5\n', "pf.adapt_rat: unknown field (did you mean adapt_rate?)"),
    ('[estimator.pf]\nadapt_rate = 0.5\n', None),
])
def test_estimator_settings_name_typos_and_refuse_the_unused_table(small, tmp_path, capsys, table, said):
    from bmctl.scenario import load_scenario

    sc = tmp_path / "s.toml"
    sc.write_text(small.read_text(encoding="utf-8").replace("[controller]", table + "[controller]"), encoding="utf-8")
    if said:
        with pytest.raises(InputError, match=__import__("re").escape(said)):
            load_scenario(sc)
    else:
        load_scenario(sc)
        sc.write_text(sc.read_text(encoding="utf-8").replace("[estimator]\n", '[estimator]\nkind = "ukf"\n'), encoding="utf-8")
        with pytest.raises(InputError, match="settings of the pf estimator, but estimator.kind is 'ukf'"):
            load_scenario(sc)
        sc.write_text(sc.read_text(encoding="utf-8").replace(table, ""), encoding="utf-8")  # the particle count alone is refused too
        with pytest.raises(InputError, match="particles: a particle count, but estimator.kind is 'ukf'"):
            load_scenario(sc)
        sc.write_text(sc.read_text(encoding="utf-8").replace("particles = 300\n[controller]", "[controller]"), encoding="utf-8")
        assert load_scenario(sc).estimator.kind == "ukf"


def _lqr_with(tmp_path, *edits) -> Path:
    """lqr-baseline.toml with ``edits`` ((old, new) line replacements) in ``tmp_path``."""
    text = (ROOT / "controllers" / "lqr-baseline.toml").read_text(encoding="utf-8")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / "c.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("edits, said", [
    # the guard rounds each interval alone: a 30-min milling interval then a rest made a 30-min period
    ((("min_mill_min = 5.0", "min_mill_min = 45.0"),), "mill.min_mill_min: 45 min is longer than the control interval"),
    ((("min_rest_min = 5.0", "min_rest_min = 45.0"),), "mill.min_rest_min: 45 min is longer than the control interval"),
    # no rpm could be milled at: the trial rested the whole batch without a word
    ((("rpm_min_milling = 100.0", "rpm_min_milling = 400.0"), ("rpm_max = 500.0", "rpm_max = 300.0")),
     "mill.rpm_min_milling: 400 rpm is above bounds.rpm_max (300 rpm)"),
    # the LQR milled its nominal 1.0 through a milling_max of 0.1
    ((("milling_max = 1.0", "milling_max = 0.1"),), "lqr.milling: 1 is outside [bounds.milling_min, bounds.milling_max]"),
])
def test_a_controller_the_mill_limits_make_infeasible_is_refused_naming_the_field(small, tmp_path, edits, said):
    from bmctl.scenario import load_scenario

    ctrl = _lqr_with(tmp_path, *edits)
    sc = tmp_path / "s.toml"
    sc.write_text(small.read_text(encoding="utf-8").replace(f"{ROOT}/controllers/mpc-fast.toml", str(ctrl)), encoding="utf-8")
    with pytest.raises(InputError, match=__import__("re").escape(said)):
        load_scenario(sc)


def test_sampling_faster_than_the_control_interval_is_refused(small, tmp_path):
    """every_h = 0.25 with 0.5 h intervals took one sample per interval: half those asked for, unsaid."""
    from bmctl.scenario import load_scenario

    sc = tmp_path / "s.toml"
    sc.write_text(small.read_text(encoding="utf-8").replace("every_h = 1.0", "every_h = 0.25"), encoding="utf-8")
    with pytest.raises(InputError, match=r"sampling\.every_h: 0\.25 h is shorter than the control interval \(0\.5 h"):
        load_scenario(sc)
    sc.write_text(small.read_text(encoding="utf-8").replace("every_h = 1.0", "every_h = 0.5"), encoding="utf-8")
    load_scenario(sc)


def test_campaign_init_refuses_a_minimum_the_interval_guard_cannot_keep(tmp_path, capsys):
    """As a trial: an LQR campaign with 45-min minimum milling on 0.5 h intervals would advise periods of 30 min."""
    from bmctl.cli import main

    ctl = _lqr_with(tmp_path, ("min_mill_min = 5.0", "min_mill_min = 45.0"))
    rc = main(["campaign", "init", str(tmp_path / "camp"), "--model", str(ROOT / "models" / "alni-1to1-300rpm-lab.toml"),
               "--controller", str(ctl), "--target", "s_mean_um=35"])
    err = capsys.readouterr().err
    assert rc == 2 and "mill.min_mill_min: 45 min is longer than the control interval" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "camp").exists()


def test_a_missed_target_is_explained_by_the_plans_binding_limits(tmp_path, capsys):
    """s_mean 25 µm in 2 h on the lab card is out of reach under the 80 °C ceiling: the trial misses it
    and says what bound its first plan (the ceiling) and its last; summary.json keeps both lists.
    It printed the miss alone."""
    sc = tmp_path / "far.toml"
    sc.write_text(SMALL.format(root=ROOT).replace("s_mean_um = 50.0", "s_mean_um = 25.0")
                  .replace("mpc-fast.toml", "mpc-default.toml"), encoding="utf-8")
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if "missed by more than 2 %" in ln or "missed by more than 2%" in ln]
    assert len(line) == 1 and "binding limits of the first plan: vial-temperature ceiling (80 °C)" in line[0]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text(encoding="utf-8"))
    assert any(b.startswith("vial-temperature ceiling") for b in summary["binding_first"])
    assert isinstance(summary["binding_last"], list)


def test_a_plant_factor_past_the_card_limit_is_one_line(small, tmp_path, capsys):
    """gamma_factor x the plant card's gamma above the 1 um^-2 a card allows: the scenario file and
    the factor named, before --out is made (it was a pydantic traceback from the plant's card)."""
    card = tmp_path / "card.toml"
    card.write_text((ROOT / "models" / "alni-1to1-300rpm-lab.toml").read_text(encoding="utf-8")
                    .replace("gamma_per_um2 = 1.82e-4", "gamma_per_um2 = 0.02"), encoding="utf-8")
    sc = tmp_path / "s.toml"
    sc.write_text(small.read_text(encoding="utf-8").replace("gamma_factor = 1.3", f'gamma_factor = 99.0\nmodel = "{card}"'), encoding="utf-8")
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{sc}: plant.gamma_factor: 99 takes the card's stochastic.gamma_per_um2" in err[0], err
    assert not (tmp_path / "o").exists()


def test_d50_target_is_judged_on_the_powder_and_shown_through_the_size_law(tmp_path):
    """A d50_um target is steered as the size law's D50 of (s_mean, s_std) but judged on the plant's own
    particles; summary.json gave only the latter, so a miss could not be told apart from the law's misfit."""
    from bmctl.stats import weibull_size_stats

    p = tmp_path / "d50.toml"
    p.write_text(SMALL.format(root=ROOT).replace("hours = 2", "hours = 1")
                 .replace("s_mean_um = 50.0", "d50_um = 60.0"), encoding="utf-8")
    summary = run_trial(p, tmp_path / "o", seed=2)
    true = summary["final_true"]
    law = weibull_size_stats(true["s_mean_um"], true["s_std_um"])  # Justus k = cv^-1.086 (docs/fidelity.md)
    assert summary["final_true_law"] == {"d50_um": pytest.approx(float(law["d50_um"]), rel=1e-12)}
    assert summary["final_error"]["d50_um"] == pytest.approx((true["d50_um"] - 60.0) / 60.0, rel=1e-9)
    assert true["d50_um"] != pytest.approx(summary["final_true_law"]["d50_um"], rel=1e-6)
