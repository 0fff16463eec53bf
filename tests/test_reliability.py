"""Known hostile inputs: each gives exit 2 and one line naming the file, flag or field, or a
correct run where the input is legitimate; Ctrl-C leaves no half output; no code-bearing loads."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from bmctl.cli import main

from . import fuzzlib

ROOT = fuzzlib.ROOT
FAN = ROOT / "models" / "alni-1to1-400rpm-fan.toml"


def _err(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    return err[0]


def _table(path: Path, rows: list[tuple[str, str]], header: str = "s_um,r") -> Path:
    path.write_text(header + "\n" + "\n".join(f"{a},{b}" for a, b in rows) + "\n", encoding="utf-8")
    return path


def _sample(n: int = 59) -> list[tuple[str, str]]:
    rng = np.random.default_rng(1)
    return [(f"{s:.4g}", f"{r:.4g}") for s, r in zip(rng.normal(40, 6, n), rng.uniform(0.01, 0.1, n))]


def _card_with(tmp_path: Path, edit) -> Path:
    data = tomllib.loads(FAN.read_text(encoding="utf-8"))
    edit(data)
    p = tmp_path / "card.toml"
    p.write_text(fuzzlib.toml_dumps(data), encoding="utf-8")
    return p


@pytest.mark.parametrize("value", [0.0, 1e-320])
def test_a_card_that_traps_no_powder_is_refused(tmp_path, capsys, value):
    def none(d):
        d["partition"]["coated_fraction"] = value
    card = _card_with(tmp_path, none)
    assert main(["card", "show", str(card)]) == 2
    assert "card.toml: partition.coated_fraction" in _err(capsys)


# --- particle tables ------------------------------------------------------------------------------

@pytest.mark.parametrize("value", [pytest.param("1e308", marks=pytest.mark.slow), "1e-320", "5e-324", "1e-300", "2e4"])
@pytest.mark.parametrize("command", ["measure", "estimate"])
def test_table_sizes_outside_physics_are_refused(tmp_path, capsys, value, command):
    rows = _sample()
    rows[17] = (value, "0.02")
    t = _table(tmp_path / "t.csv", rows)
    argv = (["measure", str(t), "--out", str(tmp_path / "m.csv")] if command == "measure" else
            ["estimate", str(FAN), "--samples", str(t), "--times", "1", "--out", str(tmp_path / "e.csv")])
    assert main(argv) == 2
    line = _err(capsys)
    assert "t.csv: row 19, column s_um" in line and "[0.001, 10000] µm" in line
    assert not list(tmp_path.glob("[me].*"))


def test_area_that_rounds_r_to_one_is_refused(tmp_path, capsys):
    t = _table(tmp_path / "t.csv", [("1256.6", "125.66"), ("1256.6", "1e30")], "area_um2,perimeter_um")
    assert main(["measure", str(t)]) == 2
    assert "row 3, column perimeter_um" in _err(capsys)


def test_area_of_1e308_is_refused(tmp_path, capsys):
    t = _table(tmp_path / "t.csv", [("1256.6", "125.66"), ("1e308", "1e308")], "area_um2,perimeter_um")
    assert main(["measure", str(t)]) == 2
    assert "row 3, column area_um2" in _err(capsys)


@pytest.mark.parametrize("scale", ["1e-300", "1e-5", "1e9", "5000"])
def test_measure_refuses_an_absurd_pixel_size(tmp_path, capsys, scale):
    img = tmp_path / "img.png"
    img.write_bytes(fuzzlib.synthetic_micrograph(__import__("random").Random(3)))
    assert main(["measure", str(img), "--um-per-px", scale, "--out", str(tmp_path / "m.csv")]) == 2
    assert _err(capsys).startswith("bmctl: error: --um-per-px: ")
    assert not (tmp_path / "m.csv").exists()


@pytest.mark.slow
def test_a_decompression_bomb_is_refused_before_decoding(tmp_path, capsys):
    img = tmp_path / "bomb.tif"
    img.write_bytes(fuzzlib.bomb_tiff())
    assert img.stat().st_size < 2_000_000
    assert main(["measure", str(img), "--um-per-px", "0.5"]) == 2
    assert "bomb.tif: image too large (144,000,000 pixels, limit 100,000,000)" in _err(capsys)


@pytest.mark.slow
def test_measure_writes_a_table_its_reader_accepts(tmp_path, capsys):
    from bmctl.measure.tables import read_table

    img = tmp_path / "img.png"
    img.write_bytes(fuzzlib.synthetic_micrograph(__import__("random").Random(3)))
    assert main(["measure", str(img), "--um-per-px", "0.5", "--min-area-px", "10", "--out",
                 str(tmp_path / "m.csv")]) == 0
    t = read_table(tmp_path / "m.csv")
    assert len(t) >= 3 and np.all((t.s_um > 1) & (t.s_um < 20)) and np.all((t.r >= 0) & (t.r < 1))


# --- readings and the filter ----------------------------------------------------------------------

@pytest.mark.parametrize("temps", ["1e9,25", "-300,25", "25,-51"])
def test_estimate_refuses_impossible_readings(tmp_path, capsys, temps):
    a, b = _table(tmp_path / "a.csv", _sample()), _table(tmp_path / "b.csv", _sample())
    argv = ["estimate", str(FAN), "--samples", str(a), str(b), "--times", "0.5,1", f"--temperatures={temps}",
            "--out", str(tmp_path / "e.csv")]
    assert main(argv) == 2
    line = _err(capsys)
    assert line.startswith("bmctl: error: --temperatures: reading") and "660.3] °C" in line  # Al melts at 660.3 C
    assert not (tmp_path / "e.csv").exists()


def test_library_boundary_refuses_bad_samples():
    from bmctl.config import load_card
    from bmctl.errors import InputError
    from bmctl.estimate.run import Sample, check_reading, check_sample

    card = load_card(FAN)
    with pytest.raises(InputError, match=r"s_um = 1e-320"):
        check_sample(Sample(1.0, np.array([40.0, 1e-320]), np.array([0.05, 0.05]), source="x.csv"))
    with pytest.raises(InputError, match=r"r = 1 outside"):
        check_sample(Sample(1.0, np.array([40.0]), np.array([1.0]), source="x.csv"))
    with pytest.raises(InputError, match=r"reading -300 °C"):
        check_reading(card, -300.0, "x")
    assert check_reading(card, 80.0, "x") == 80.0


def test_collapsed_update_is_flagged_in_the_table():
    from bmctl.estimate.filter import Estimate
    from bmctl.estimate.run import estimate_rows

    names = ("s_mean_um",)
    ok = Estimate(1.0, names, np.array([40.0]), np.array([38.0]), np.array([42.0]), ess=700.0)
    one = Estimate(2.0, names, np.array([40.0]), np.array([40.0]), np.array([40.0]), ess=1.0)
    header, rows = estimate_rows([ok, one])
    k = header.index("degenerate")
    assert [r[k] for r in rows] == [0, 1]


@pytest.mark.slow
def test_estimate_warns_when_the_filter_collapses(tmp_path, capsys, monkeypatch):
    """The CLI's reporting path: a filter whose second update collapsed onto one particle."""
    from bmctl.estimate import run as est_run
    from bmctl.estimate.filter import Estimate

    def collapsing(model, samples, segments, settings=None, seed=0, **kw):
        names = ("s_mean_um", "s_std_um", "r_mean", "r_std", "gamma_mult", "delta_mult")
        one = np.array([40.0, 4.0, 0.05, 0.02, 1.0, 1.0])
        ests = [Estimate(s.t_h, names, one, one * 0.9, one * 1.1, ess=ess) for s, ess in zip(samples, (150.0, 1.0))]
        return type("PF", (), {"n_resampled": 1})(), ests

    monkeypatch.setattr(est_run, "run_filter", collapsing)
    a, b = _table(tmp_path / "a.csv", _sample()), _table(tmp_path / "b.csv", _sample())
    rc = main(["estimate", str(FAN), "--samples", str(a), str(b), "--times", "0.2,0.4", "--particles", "200",
               "--out", str(tmp_path / "e.csv")])
    cap = capsys.readouterr()
    assert rc == 0
    rows = fuzzlib._rows(tmp_path / "e.csv")[1]
    assert [r["degenerate"] for r in rows] == ["0", "1"]
    warn = [ln for ln in cap.err.splitlines() if "degenerate update" in ln]
    assert len(warn) == 1 and warn[0].startswith("bmctl: warning: 0.4 h: degenerate update")


# --- the vial's temperature -----------------------------------------------------------------------

def test_peak_temperature_is_the_first_order_solution():
    from bmctl.cards import peak_temperature_c
    from bmctl.config import load_card
    from bmctl.plant.kinematics import kinematics

    card = load_card(FAN)
    th = card.thermal
    p = kinematics(card, 400.0).mean_power_W
    t_ss = th.ambient_C + p * th.cooling_time_s / th.heat_capacity_J_per_K
    want = t_ss + (th.ambient_C - t_ss) * math.exp(-0.5 * 3600 / th.cooling_time_s)
    # 0.5 h milling, then a rest: the peak is at the end of the milling
    assert peak_temperature_c(card, [(0.5, 400.0), (1.0, 0.0)]) == pytest.approx((want, 0.5), rel=1e-12)


@pytest.mark.slow
def test_simulate_records_the_predicted_temperature(tmp_path, capsys):
    from bmctl.cards import peak_temperature_c
    from bmctl.config import load_card

    assert main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    rows = fuzzlib._rows(tmp_path / "moments.csv")[1]
    peak, _ = peak_temperature_c(load_card(FAN), [(0.2, 400.0)])
    assert float(rows[-1]["temperature_c"]) == pytest.approx(peak, abs=0.01)


@pytest.mark.parametrize("command", ["simulate", "whatif"])
def test_a_run_above_the_melting_point_stops(tmp_path, capsys, command):
    def fast(d):
        d["mill"]["rpm_max"] = 1500
    card = _card_with(tmp_path, fast)
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = 12\nrpm = 1200\n", encoding="utf-8")
    argv = (["simulate", str(card), "--rpm", "1200", "--hours", "12", "--particles", "200", "--out",
             str(tmp_path / "o")] if command == "simulate" else
            ["whatif", str(card), str(sched), "--seeds", "1", "--particles", "200", "--out", str(tmp_path / "o")])
    assert main(argv) == 2
    line = _err(capsys)
    assert ("--rpm" if command == "simulate" else "s.toml") in line
    assert "above 660.3 °C (the melting point of Al" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_whatif_warns_outside_the_validity_range(tmp_path, capsys):
    def cool(d):
        d["validity"] = {"temperature_max_C": 30.0}
    card = _card_with(tmp_path, cool)
    sched = tmp_path / "s.toml"
    sched.write_text("[[segment]]\nhours = 0.2\nrpm = 400\n", encoding="utf-8")
    assert main(["whatif", str(card), str(sched), "--seeds", "1", "--particles", "200", "--out",
                 str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "bmctl: warning: s: alni-1to1-400rpm-fan: vial temperature" in err and "maximum 30 °C" in err


# --- Ctrl-C ---------------------------------------------------------------------------------------

def test_ctrl_c_in_the_plant_exits_130_and_leaves_no_output(tmp_path, capsys, monkeypatch):
    from bmctl.plant import plant

    calls = []

    def interrupted(self, *a, **k):
        calls.append(1)
        raise KeyboardInterrupt

    monkeypatch.setattr(plant.Plant, "_run", interrupted)
    out = tmp_path / "o"
    assert main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(out),
                 "--no-progress"]) == 130
    assert calls and _err(capsys).startswith("bmctl: interrupted (Ctrl-C)")
    assert not out.exists() or not any(out.iterdir())


def test_ctrl_c_leaves_no_library_traceback_after_its_line(tmp_path, capsys, monkeypatch):
    """An object whose __init__ the interrupt cut short raises in its __del__ (pyparsing's Forward
    during matplotlib's import): Python prints that as "Exception ignored in ..." with a traceback
    unless the interrupted run has silenced it."""
    import sys

    from bmctl.plant import plant

    class HalfBuilt:
        def __del__(self):
            raise AttributeError("'HalfBuilt' object has no attribute 'expr'")

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sys, "unraisablehook", sys.__unraisablehook__)  # Python's own (it prints); restored after
    monkeypatch.setattr(plant.Plant, "_run", interrupted)
    assert main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(tmp_path / "o"),
                 "--no-progress"]) == 130
    obj = HalfBuilt()
    del obj  # as the interpreter collects it after the run
    err = capsys.readouterr().err
    assert err.startswith("bmctl: interrupted (Ctrl-C)") and err.count("\n") == 1, err


def test_ctrl_c_inside_compiled_code_is_an_interrupt_not_a_traceback(tmp_path, capsys, monkeypatch):
    """numba reports Ctrl-C in a compiled loop as a SystemError whose cause is the KeyboardInterrupt."""
    from bmctl.plant import plant

    def interrupted(self, *a, **k):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(<function run_steps>) returned a result with an exception set") from exc

    monkeypatch.setattr(plant.Plant, "_run", interrupted)
    out = tmp_path / "o"
    assert main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(out),
                 "--no-progress"]) == 130
    assert _err(capsys).startswith("bmctl: interrupted (Ctrl-C)")

    def broken(self, *a, **k):  # a SystemError of its own is not swallowed
        raise SystemError("a bug")

    monkeypatch.setattr(plant.Plant, "_run", broken)
    with pytest.raises(SystemError, match="a bug"):
        main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(out), "--no-progress"])


@pytest.mark.slow
def test_ctrl_c_while_writing_leaves_no_half_output_set(tmp_path, capsys, monkeypatch):
    from bmctl import plots

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "moments_over_time", interrupted)  # the last figure of the set
    out = tmp_path / "o"
    assert main(["simulate", str(FAN), "--hours", "0.2", "--particles", "200", "--out", str(out),
                 "--no-progress"]) == 130
    assert _err(capsys).startswith("bmctl: interrupted")
    assert not out.exists()  # the folder the set made is removed with its temporary files (it stayed empty)


SIGTERM_RUN = """
import os, signal, sys
from bmctl import cli, plots

def terminated(*a, **k):  # as `kill`, `timeout` or a batch scheduler ends the job while the figures are written
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(10 ** 7):  # the handler runs between bytecodes
        pass
    raise AssertionError("SIGTERM was not raised")

plots.moments_over_time = terminated
sys.argv = ["bmctl", "simulate", sys.argv[1], "--hours", "0.2", "--particles", "200", "--out", sys.argv[2],
            "--no-progress"]
sys.exit(cli.main())
"""


def test_sigterm_while_writing_exits_143_and_leaves_no_temporary_file(tmp_path):
    """SIGTERM ended the process at once: the set's hidden temporary files (.moments.csv.XXXX.csv, ...)
    stayed in the output folder for good. It is handled as Ctrl-C is, in the command's own process."""
    import subprocess
    import sys

    out = tmp_path / "run" / "o"
    r = subprocess.run([sys.executable, "-c", SIGTERM_RUN, str(FAN), str(out)], capture_output=True, text=True,
                       timeout=300, cwd=tmp_path)
    assert r.returncode == 143, r.stderr
    assert r.stderr.startswith("bmctl: terminated (SIGTERM): no output was left half-written"), r.stderr
    assert r.stderr.count("\n") == 1, r.stderr
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == []


# --- bounded work ---------------------------------------------------------------------------------

def test_design_refuses_a_solver_beyond_the_budget(tmp_path, capsys):
    ctrl = tmp_path / "c.toml"
    ctrl.write_text((ROOT / "controllers" / "mpc-default.toml").read_text(encoding="utf-8").replace("interval_h = 0.5",
                                                                                    "interval_h = 0.02"), encoding="utf-8")
    assert "interval_h = 0.02" in ctrl.read_text(encoding="utf-8")
    assert main(["design", str(FAN), "--target", "s_mean_um=30", "--hours", "1000", "--controller", str(ctrl),
                 "--out", str(tmp_path / "o")]) == 2
    line = _err(capsys)
    assert "--hours" in line and "BMCTL_BUDGET_CPU_H" in line and "over the budget of 1 h" in line


@pytest.mark.parametrize("command", ["design", "identify"])
def test_solver_commands_obey_the_budget_variable(tmp_path, capsys, monkeypatch, command):
    monkeypatch.setenv("BMCTL_BUDGET_CPU_H", "1e-6")
    argv = (["design", str(FAN), "--target", "s_mean_um=30", "--hours", "12", "--out", str(tmp_path / "o")]
            if command == "design" else
            ["identify", str(FAN), "--quick", "--quiet", "--out", str(tmp_path / "c.moments.toml")])
    assert main(argv) == 2
    line = _err(capsys)
    assert "over the budget of 1e-06 h" in line and "BMCTL_BUDGET_CPU_H" in line
    assert ("--hours" if command == "design" else "--particles") in line


def test_design_hours_beyond_a_batch_are_refused(tmp_path, capsys):
    assert main(["design", str(FAN), "--target", "s_mean_um=30", "--hours", "1e300", "--out", str(tmp_path)]) == 2
    assert "--hours: must be in [1 s, 1000 h] (got 1e300)" in _err(capsys)


def test_design_work_is_finite_for_any_horizon():
    from bmctl.cards import design_work

    w = design_work(1e300, 1 / 60)
    assert all(math.isfinite(v) or v == math.inf for v in w.values()) and w["cpu_s"] > 1e10


def test_identify_work_grows_with_its_flags():
    from bmctl.cards import identify_work
    from bmctl.config import load_card
    from bmctl.moments import identify as ident

    card = load_card(FAN)
    specs = ident.design(card, 0, True, 0)
    small = identify_work(card, [(specs, 1)], 200, ident.DT_H)
    big = identify_work(card, [(specs, 2)], 2000, ident.DT_H)
    assert big["impacts"] == pytest.approx(20 * small["impacts"], rel=1e-9)


# --- no code from the user's folders --------------------------------------------------------------

CODE_LOADS = re.compile(r"pickle\.loads?\(|allow_pickle\s*=\s*True|yaml\.(unsafe_)?load\(|\beval\(|\bexec\(|"
                        r"marshal\.loads?\(|shelve\.open|torch\.load|joblib\.load|dill\.")


def test_no_code_bearing_loads():
    hits = []
    for path in sorted((ROOT / "bmctl").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        text = path.read_text(encoding="utf-8")
        for m in CODE_LOADS.finditer(text):
            hits.append(f"{rel}: {m.group(0)}")
        for line in text.splitlines():  # the call's arguments may nest parentheses: look at its line
            if "np.load(" in line and "allow_pickle=False" not in line:
                hits.append(f"{rel}: np.load without allow_pickle=False")
    assert hits == []


# --- trial --resume with damaged files (found by the resume fuzz, tests/fuzzlib.py) ------------------------

def _trajectory(path: Path, rows: list[list[str]], tail: str = "") -> Path:
    from bmctl.trial import trajectory_header

    path.write_text("\n".join(",".join(r) for r in [trajectory_header(), *rows]) + "\n" + tail, encoding="utf-8")
    return path


def _row(step: int) -> list[str]:
    from bmctl.trial import trajectory_header

    row = [str(step), str(0.5 * (step + 1))] + ["1.5"] * (len(trajectory_header()) - 2)
    row[trajectory_header().index("solver_status")] = "ok"
    return row


def test_resume_keeps_complete_rows_and_drops_a_torn_one(tmp_path):
    from bmctl.trial import _kept_rows

    traj = _trajectory(tmp_path / "trajectory.csv", [_row(0), _row(1)], tail="2,1.5,30")
    kept = _kept_rows(traj, 2)
    assert kept.count("\n") == 3 and "2,1.5,30" not in kept
    assert _kept_rows(traj, 1).count("\n") == 2  # the checkpoint is behind the file: its rows only


@pytest.mark.parametrize("damage, named", [
    (lambda r: r[1].append("7"), "row 3: 37 fields"),
    (lambda r: r[1].pop(), "row 3: 35 fields"),
    (lambda r: r[0].__setitem__(0, "5"), "row 2: step '5'"),
    (lambda r: r[0].__setitem__(4, "abc"), "row 2: true_s_mean_um: not a number"),
    (lambda r: r[0].__setitem__(4, "nan"), "row 2: true_s_mean_um: not finite"),
])
def test_resume_refuses_a_damaged_kept_row(tmp_path, damage, named):
    from bmctl.errors import InputError
    from bmctl.trial import _kept_rows

    rows = [_row(0), _row(1)]
    damage(rows)
    traj = _trajectory(tmp_path / "trajectory.csv", rows)
    with pytest.raises(InputError, match=f"trajectory.csv: {re.escape(named)}"):
        _kept_rows(traj, 2)


@pytest.mark.parametrize("content, named", [
    (b"", "no complete header row"), (b"\xce\x00\xff garbage", "not UTF-8"), (b"a,b\n", "row 1: not the trajectory header"),
])
def test_resume_refuses_an_empty_or_foreign_trajectory(tmp_path, content, named):
    from bmctl.errors import InputError
    from bmctl.trial import _kept_rows

    (tmp_path / "trajectory.csv").write_bytes(content)
    with pytest.raises(InputError, match=named):
        _kept_rows(tmp_path / "trajectory.csv", 0)


def test_resume_refuses_a_checkpoint_of_another_form():
    from bmctl.trial import _misfit

    fresh = {"loop": {"k": 0, "u_prev": None, "est": {"s_mean_um": 40.0}},
             "mill": {"s": np.ones(4), "counts": [0, 0, "ok"]}}
    good = {"loop": {"k": 2, "u_prev": [300.0, 1.0], "est": {"s_mean_um": 52.5}},
            "mill": {"s": np.full(4, 2.0), "counts": [3, 1, "ok"]}}
    assert _misfit(fresh, good) is None
    for path, value, why in [
        (("mill", "counts", 2), 1e9, "/mill/counts/2: expected text"),
        (("loop", "est", "s_mean_um"), [40.0, 40.0], "/loop/est/s_mean_um: expected a number"),
        (("loop", "est", "s_mean_um"), float("inf"), "/loop/est/s_mean_um: not finite"),
        (("loop", "k"), 1.5, "/loop/k: expected a number"),
        (("loop", "u_prev"), [float("nan"), 1.0], "/loop/u_prev: expected nothing, finite numbers"),
        (("loop", "u_prev"), [{"a": np.array(["x"])}], "/loop/u_prev: expected nothing, finite numbers"),
        (("mill", "s"), np.ones(5), "/mill/s: expected a float64 array of shape (4,)"),
        (("mill", "s"), np.array([1.0, np.nan, 1.0, 1.0]), "/mill/s: not finite"),
        (("mill",), {"s": np.ones(4)}, "/mill: expected a table"),
    ]:
        bad = {"loop": dict(good["loop"], est=dict(good["loop"]["est"])), "mill": dict(good["mill"])}
        d = bad
        for k in path[:-1]:
            d = d[k] if not isinstance(d[k], list) else d.__setitem__(k, list(d[k])) or d[k]
        d[path[-1]] = value
        assert (_misfit(fresh, bad) or "").startswith(why), (path, _misfit(fresh, bad))


@pytest.mark.slow
@pytest.mark.parametrize("damage, outcome", [("torn", 0), ("long-row", 2), ("garbage", 2), ("leaf", 2)])
def test_resume_of_a_damaged_trial_carries_on_or_names_the_file(tmp_path, capsys, damage, outcome):
    import shutil

    from bmctl.checkpoint import load_state, save_state

    fx = fuzzlib.fixtures()
    out = tmp_path / "t"
    shutil.copytree(fx / "trial-1", out)
    ref = fuzzlib.reference_rows()
    traj = out / "trajectory.csv"
    if damage == "torn":
        traj.write_text(traj.read_text(encoding="utf-8") + ",".join(ref[2])[:40], encoding="utf-8")
    elif damage == "long-row":
        traj.write_text(",".join(ref[0]) + "\n" + ",".join(ref[1] + ["7"]) + "\n", encoding="utf-8")
    elif damage == "garbage":
        traj.write_bytes(b"\xce\x00\xff" * 100)
    else:
        state = load_state(out / "checkpoint.npz")
        state["loop"]["est"]["s_std_um"] = [1.0, 2.0]
        save_state(out / "checkpoint.npz", state)
    rc = main(["trial", str(fx / "resume.toml"), "--resume", str(out), "--no-progress"])
    cap = capsys.readouterr()
    assert rc == outcome, cap.err
    if outcome == 2:
        err = _err_lines(cap.err)
        assert len(err) == 1 and ("trajectory.csv" in err[0] or "checkpoint.npz" in err[0]), err
    else:
        assert fuzzlib.check_resumed(exact=True)(out) == []


def _err_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.strip()]


def test_an_output_never_replaces_a_pipe_or_device(tmp_path):
    """An atomic write renames its temporary file onto the destination: onto a FIFO (or, as root,
    /dev/null) that replaced the special file itself with a regular one."""
    import os
    import stat

    from bmctl.io import write_text

    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="not a regular file"):
        write_text(fifo, "x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.fifo"]  # no temporary file left
