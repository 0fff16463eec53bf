"""A trial scenario's batch length and target are checked as ``bmctl design`` checks them, in one
line naming the scenario file and the field, before anything is written; a missed target is
always said.

* ``hours = 0.05`` milled 3 min (``0.0003``: 1 s) though a schedule of whole minutes needs the
  mill's minimum milling period, at least 5 min, which ``design --hours 0.05`` refuses: the
  scenario's control interval was cut to the batch after the interval checks.
* a target out of range (``r_mean = 5``) was refused as ``target: r_mean: ...``, without the file.
* a 5.7 % miss of a plan without binding limits was printed without a miss line.
"""

import json

import pytest

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.scenario import load_scenario

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CTRL = ROOT / "controllers"

SCENARIO = """model = "{card}"
hours = {hours}
target = {target}
[scenario]
name = "inputs"
description = "a short trial on the lab card"
[plant]
particles = 300
[sampling]
every_h = {every}
particles = 60
[estimator]
particles = 100
[controller]
config = "{ctrl}"
"""


def _scenario(tmp_path, hours=1.0, target="{ s_mean_um = 45.0 }", ctrl="mpc-default", every=None):
    path = tmp_path / "sc.toml"
    path.write_text(SCENARIO.format(card=CARD, hours=hours, target=target, ctrl=CTRL / f"{ctrl}.toml",
                                    every=every if every is not None else max(hours, 1 / 60)), encoding="utf-8")
    return path


def _run(argv, capsys) -> tuple[int, list[str], str]:
    capsys.readouterr()
    rc = main(argv)
    cap = capsys.readouterr()
    return rc, cap.err.strip().splitlines(), cap.out


# --- batch length ------------------------------------------------------------------------------------
@pytest.mark.parametrize("hours, minutes", [(0.05, "3"), (0.0003, "0.018")])
def test_a_batch_under_the_minimum_milling_period_is_refused_as_design_refuses_it(tmp_path, capsys, hours, minutes):
    sc = _scenario(tmp_path, hours=hours, target="{ d50_um = 45.0 }")
    rc, err, _ = _run(["trial", str(sc), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert rc == 2 and len(err) == 1, err
    head = f"bmctl: error: {sc}: hours: "
    assert err[0].startswith(head + f"a batch of {hours:g} h ({minutes} min) is shorter than the 5 min"), err[0]
    assert not (tmp_path / "out").exists()
    rc, derr, _ = _run(["design", str(CARD), "--target", "d50_um=45", "--hours", f"{hours:g}", "--controller",
                        str(CTRL / "mpc-default.toml"), "--out", str(tmp_path / "design")], capsys)
    assert rc == 2 and len(derr) == 1 and derr[0].startswith("bmctl: error: --hours: ")
    assert err[0].removeprefix(head) == derr[0].removeprefix("bmctl: error: --hours: ")  # one rule, one message


@pytest.mark.parametrize("ctrl", ["lqr-baseline", "recipe-300rpm-continuous"])
def test_every_controller_kind_has_the_same_shortest_batch(tmp_path, ctrl):
    with pytest.raises(InputError, match=r"sc\.toml: hours: a batch of 0\.05 h \(3 min\) is shorter than the 5 min"):
        load_scenario(_scenario(tmp_path, hours=0.05, ctrl=ctrl))


def test_a_batch_of_the_minimum_milling_period_or_longer_is_accepted(tmp_path):
    """One interval cut to the batch end: 6 min of mpc-default's 30-min interval."""
    assert load_scenario(_scenario(tmp_path, hours=0.1)).hours == 0.1


def test_the_mills_own_minimum_period_sets_the_shortest_batch(tmp_path):
    ctrl = tmp_path / "lqr-10min.toml"
    ctrl.write_text((CTRL / "lqr-baseline.toml").read_text(encoding="utf-8").replace("min_mill_min = 5.0", "min_mill_min = 10.0"), encoding="utf-8")
    sc = _scenario(tmp_path, hours=0.1)
    sc.write_text(sc.read_text(encoding="utf-8").replace(str(CTRL / "mpc-default.toml"), str(ctrl)), encoding="utf-8")
    with pytest.raises(InputError, match=r"hours: a batch of 0\.1 h \(6 min\) is shorter than the 10 min .* in "
                                         r".*lqr-10min\.toml"):
        load_scenario(sc)


# --- target ranges -----------------------------------------------------------------------------------
@pytest.mark.parametrize("target, want", [
    ("{ r_mean = 5.0 }", "target.r_mean: must be in (0, 1) (got 5)"),
    ("{ s_mean_um = 1e9 }", "target.s_mean_um: must be in (0.001, 100000) (got 1e+09)"),
    ("{ r_mean = [0.5, 2.0] }", "target.r_mean: must be in (0, 1) (got 2)"),
    ("{ span = 200.0 }", "target.span: must be in (0, 100) (got 200)"),
    ("{ d50_um = 45.0, d90_um = 40.0 }", "target: d90_um (40) must be above d50_um (45): no size law has D90 <= D50"),
])
def test_a_target_out_of_range_names_the_scenario_file_and_field(tmp_path, capsys, target, want):
    sc = _scenario(tmp_path, target=target, ctrl="recipe-300rpm-continuous")
    rc, err, _ = _run(["trial", str(sc), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert rc == 2 and err == [f"bmctl: error: {sc}: {want}"], err
    assert not (tmp_path / "out").exists()


def test_a_controller_files_target_out_of_range_names_the_key(tmp_path):
    from bmctl.control import validate_controller

    with pytest.raises(InputError, match=r"^c\.toml: target\.r_mean: must be in \(0, 1\) \(got 5\)$"):
        validate_controller({"kind": "mpc", "target": {"r_mean": 5.0}}, "c.toml")
    with pytest.raises(InputError, match=r"^c\.toml: reference\[1\]\.s_mean_um: must be in \(0\.001, 100000\)"):
        validate_controller({"kind": "mpc", "reference": [{"from_h": 0.0, "r_mean": 0.05},
                                                          {"from_h": 1.0, "s_mean_um": 1e9}]}, "c.toml")


# --- a missed target ---------------------------------------------------------------------------------
def test_a_miss_without_binding_limits_is_still_said(tmp_path, capsys):
    """The open-loop recipe's plans record no binding limits: 1 h at 300 rpm misses s_mean 45 um by far."""
    sc = _scenario(tmp_path, hours=1.0, ctrl="recipe-300rpm-continuous", every=0.5)
    rc, err, out = _run(["trial", str(sc), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert rc == 0, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text(encoding="utf-8"))
    assert abs(summary["final_error"]["s_mean_um"]) > 0.02
    assert summary["binding_first"] == [] and summary["binding_last"] == []
    lines = [ln for ln in out.splitlines() if "missed by more than" in ln]
    assert lines == ["  missed by more than 2% (s_mean_um)"], out
