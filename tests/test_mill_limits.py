"""Mill limits, D-value/window targets and the phase-pattern design (docs/control.md)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bmctl.control.config import Mill, parse_target
from bmctl.control.mill import MillGuard, check_schedule, count_switches, dwell_minutes, round_rpm
from bmctl.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
MILL = Mill(min_mill_min=5, min_rest_min=5, max_switches=6, rpm_min_milling=150, rpm_step=10)


def test_parse_target_points_windows_and_dvalues():
    assert parse_target("d50_um=40:50,span=1.2") == {"d50_um": (40.0, 50.0), "span": 1.2}
    with pytest.raises(InputError):
        parse_target("d50_um=50:40")
    with pytest.raises(InputError):
        parse_target("d10_um=3")


def test_rpm_steps_and_minimum():
    assert round_rpm(333.0, MILL, 500.0) == 330.0
    assert round_rpm(498.0, MILL, 497.0) == 490.0  # never above the cap
    assert round_rpm(90.0, MILL, 500.0) == 150.0


def test_dwell_minutes_respect_both_limits():
    for planned in np.linspace(0, 30, 61):
        a = dwell_minutes(planned, 30.0, MILL)
        assert a == 0 or a == 30 or (a >= 5 and 30 - a >= 5)


def test_guard_keeps_dwell_and_switch_budget_over_a_batch():
    g = MillGuard(MILL, 0.5)
    rng = np.random.default_rng(3)
    U = []
    for k in range(24):
        u, _ = g.enforce((rng.uniform(100, 500), rng.uniform(0, 1)), 0.5 * k, 500.0)
        U.append(u)
    segs = []
    for rpm, m in U:
        segs += [(m * 0.5, rpm), ((1 - m) * 0.5, 0.0)] if m > 0 else [(0.5, 0.0)]
    segs = [(h, r) for h, r in segs if h > 1e-12]
    assert count_switches(segs) <= MILL.max_switches
    assert check_schedule(segs, MILL) == []


def _design(args, tmp_path):
    return subprocess.run([sys.executable, "-m", "bmctl", "design", "models/alni-1to1-300rpm-lab.toml", *args,
                           "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=1200,
                          env={"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"})


@pytest.mark.slow
def test_design_d50_window_respects_mill_limits(tmp_path):
    from bmctl.config import read_toml
    from bmctl.control import load_controller

    r = _design(["--target", "d50_um=40:50"], tmp_path)
    assert r.returncode == 0, r.stderr
    segs = [(s["hours"], s["rpm"]) for s in read_toml(tmp_path / "schedule.toml")["segment"]]
    mill = load_controller(ROOT / "controllers/mpc-default.toml").mill
    assert check_schedule(segs, mill) == []


@pytest.mark.slow
def test_design_unreachable_target_is_explained(tmp_path):
    r = _design(["--target", "s_mean_um=5", "--hours", "2"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "warning: target out of reach" in r.stdout and "binding:" in r.stdout


@pytest.mark.slow
def test_min_time_design_is_shorter_than_the_batch_and_within_tolerance():
    """The target is the model's own state after 1 h of continuous 300 rpm, so a 2 h batch is
    longer than needed: min_time must pick a shorter batch that ends within the tolerance."""
    from bmctl.control import load_controller
    from bmctl.control.design import design_schedule
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(ROOT / "models/alni-1to1-300rpm-lab.toml")
    cfg = load_controller(ROOT / "controllers/mpc-default.toml")
    x1 = model.simulate(model.x0(), [[300.0, 1.0]] * 2, 0.5)[-1]
    d = design_schedule(model, {"s_mean_um": float(x1[0])}, 2.0, cfg, objective="min_time")
    assert d.result.error <= cfg.objective.tolerance
    assert d.hours < 2.0 - 1e-9
    assert len(d.pareto) == len(cfg.objective.sweep)


@pytest.mark.slow
def test_min_time_says_when_the_schedule_is_done_within_the_shortest_batch(tmp_path, capsys):
    """A window the powder enters after minutes of milling: the sweep's shortest batch (3 h) is
    reported beside the time the schedule is done, which is what min_time is asked for."""
    from bmctl.cli import main

    out = tmp_path / "d"
    assert main(["design", str(ROOT / "models/alni-1to1-300rpm-lab.toml"), "--target", "d50_um=55:65",
                 "--objective", "min_time", "--plant-seeds", "0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    done = float(text.split("the schedule is done after ")[1].split(" h")[0])
    segs = (out / "schedule.toml").read_text(encoding="utf-8").count("[[segment]]")
    assert 0 < done < 3.0 and segs >= 1 and "3 h is the shortest batch length the sweep tried" in text
