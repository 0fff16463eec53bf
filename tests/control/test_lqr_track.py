"""The LQR's integral action is on one state of the moment model (``[lqr] track``, else the first
moment the target names). A D-value as ``track`` was accepted by the config and failed in the
middle of a trial, after ``trial.json``, ``checkpoint.npz`` and a header-only ``trajectory.csv``
were written (so a rerun into the same ``--out`` was refused); a target that never names the
tracked moment (``lqr-baseline.toml`` tracks ``s_mean_um``, the scenario asked for ``d50_um``) had
the LQR hold 300 rpm the whole batch without a word. Both are refused before anything runs, in one
line naming the file, the field, the tracked moment and the target's keys."""

import pytest

from bmctl.cli import main
from bmctl.control import load_controller, make_controller, validate_controller
from bmctl.errors import InputError
from bmctl.moments import make_moment_model

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"  # track = "s_mean_um"

SCENARIO = """model = "{card}"
hours = 1
target = {target}
[scenario]
name = "lqr-track"
description = "an LQR on the lab card"
[plant]
particles = 300
[sampling]
every_h = 0.5
particles = 60
[estimator]
particles = 100
[controller]
config = "{ctrl}"
"""


@pytest.fixture(scope="module")
def model():
    return make_moment_model(str(CARD))


def _lqr(tmp_path, track: str | None) -> str:
    """lqr-baseline.toml with ``track`` (None: the line removed) in ``tmp_path``."""
    text = LQR.read_text(encoding="utf-8").replace('track = "s_mean_um"', "" if track is None else f'track = "{track}"')
    path = tmp_path / f"lqr-{track}.toml"
    path.write_text(text, encoding="utf-8")
    return str(path)


@pytest.mark.parametrize("track", ["d50_um", "d90_um", "span"])
def test_a_dvalue_track_is_refused_where_the_config_is_validated(track):
    with pytest.raises(InputError) as exc:
        validate_controller({"kind": "lqr", "lqr": {"track": track}}, "c.toml")
    msg = str(exc.value)
    assert msg.startswith("c.toml: lqr.track: a D-value is not a state of the moment model") and f"'{track}'" in msg


def _trial(tmp_path, capsys, ctrl: str, target: str) -> tuple[int, list[str], object]:
    sc = tmp_path / "sc.toml"
    sc.write_text(SCENARIO.format(card=CARD, ctrl=ctrl, target=target), encoding="utf-8")
    out = tmp_path / "out"
    capsys.readouterr()
    rc = main(["trial", str(sc), "--out", str(out), "--no-progress"])
    return rc, capsys.readouterr().err.strip().splitlines(), out


@pytest.mark.parametrize("track, target, want", [
    ("d50_um", "{ d50_um = 45.0 }", "lqr.track: a D-value is not a state of the moment model"),
    ("span", "{ span = 1.5 }", "lqr.track: a D-value is not a state of the moment model"),
    (None, "{ d50_um = 45.0 }", "sc.toml: target: names only D-values (d50_um), and an LQR tracks a moment"),
    (None, "{ d90_um = 80.0, span = 1.5 }", "sc.toml: target: names only D-values (d90_um, span)"),
    ("s_mean_um", "{ d50_um = 45.0 }", "sc.toml: target: names d50_um, never s_mean_um, the moment the LQR tracks"),
    ("s_mean_um", "{ r_mean = 0.05 }", "give a target on s_mean_um or set lqr.track to r_mean"),
])
def test_a_trial_refuses_a_target_the_lqr_cannot_track_before_writing_anything(tmp_path, capsys, track, target,
                                                                               want):
    rc, err, out = _trial(tmp_path, capsys, _lqr(tmp_path, track), target)
    assert rc == 2 and len(err) == 1 and want in err[0], err
    assert not out.exists()


def test_the_shipped_lqr_with_a_d50_target_is_refused_naming_both_keys(tmp_path, capsys):
    """lqr-baseline.toml (s_mean_um) to d50 45 um: it held 300 rpm for the whole batch, final error 173 %."""
    rc, err, out = _trial(tmp_path, capsys, str(LQR), "{ d50_um = 45.0 }")
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"bmctl: error: {tmp_path / 'sc.toml'}: target: names d50_um, never s_mean_um")
    assert f"lqr.track in {LQR}" in err[0] and "hold its rpm the whole batch" in err[0]
    assert not out.exists()


def test_a_trackable_target_still_runs(tmp_path, capsys):
    rc, err, out = _trial(tmp_path, capsys, str(LQR), "{ s_mean_um = 45.0, d50_um = 50.0 }")
    assert rc == 0, err
    assert (out / "summary.json").is_file()


def test_the_controller_refuses_an_untrackable_target_when_built_and_when_set(model):
    cfg = load_controller(LQR)
    with pytest.raises(InputError, match=r"^target: names d50_um, never s_mean_um, the moment the LQR tracks"):
        make_controller(cfg, model, {"d50_um": 45.0})
    ctrl = make_controller(cfg, model, {"s_mean_um": 45.0})
    with pytest.raises(InputError, match=r"never s_mean_um"):
        ctrl.set_target({"r_mean": 0.05}, t_end_h=3.0)
    assert ctrl.reference.at(0.0) == {"s_mean_um": 45.0} and ctrl.t_end_h != 3.0  # unchanged by the refusal
    unset = validate_controller({"kind": "lqr"}, "c.toml")
    with pytest.raises(InputError, match=r"^target: names only D-values \(d50_um\) from 1 h"):
        make_controller(unset, model, [(0.0, {"s_mean_um": 45.0}), (1.0, {"d50_um": 45.0})])


def test_a_reference_on_the_tracked_moment_at_some_times_holds_rpm_where_it_has_none(model):
    """Legitimate: s_mean_um targeted from 1 h on; before, the LQR holds its rpm and says so."""
    ctrl = make_controller(load_controller(LQR), model, [(0.0, {"r_mean": 0.05}), (1.0, {"s_mean_um": 40.0})])
    first = ctrl.plan(model.x0(), 0.0)
    assert "no target on the tracked moment: holding rpm" in first.status.reason
    assert first.rpm == pytest.approx(300.0)
    later = ctrl.plan(model.x0(), 1.0, u_prev=(300.0, 1.0))
    assert "holding rpm" not in later.status.reason and later.status.solver_status == "dlqr"


@pytest.mark.parametrize("data, want", [
    ({"kind": "lqr", "target": {"d50_um": 45.0}}, "c.toml: target: names only D-values (d50_um)"),
    ({"kind": "lqr", "lqr": {"track": "s_mean_um"}, "target": {"r_mean": 0.05}},
     "c.toml: target: names r_mean, never s_mean_um, the moment the LQR tracks (lqr.track in c.toml)"),
    ({"kind": "lqr", "reference": [{"from_h": 0.0, "s_mean_um": 40.0}, {"from_h": 6.0, "d90_um": 80.0}]},
     "c.toml: reference: names only D-values (d90_um) from 6 h"),
])
def test_an_lqr_file_whose_own_target_it_cannot_track_is_refused(data, want):
    with pytest.raises(InputError) as exc:
        validate_controller(data, "c.toml")
    assert str(exc.value).startswith(want), exc.value


def test_targets_the_lqr_tracks_pass():
    from bmctl.control.config import check_lqr_track

    check_lqr_track("s_mean_um", {"s_mean_um": 45.0, "d50_um": 50.0}, "--target", "c.toml")
    check_lqr_track(None, {"r_std": 0.01, "span": 1.5}, "--target", "c.toml")  # tracks r_std
    check_lqr_track("s_mean_um", [(0.0, {"r_mean": 0.05}), (2.0, {"s_mean_um": 40.0})], "--target", "c.toml")
    check_lqr_track("s_mean_um", {}, "--target", "c.toml")  # no target: refused by the callers that need one
    validate_controller({"kind": "lqr", "lqr": {"track": "r_mean"}, "target": {"r_mean": 0.05}}, "c.toml")


def test_campaign_init_refuses_a_target_the_lqr_cannot_track(tmp_path, capsys):
    d = tmp_path / "camp"
    rc = main(["campaign", "init", str(d), "--model", str(CARD), "--controller", str(LQR), "--target", "d50_um=45",
               "--hours", "2", "--particles", "100"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0] == (f"bmctl: error: --target: names d50_um, never s_mean_um, the moment the LQR tracks (lqr.track in "
                      f"{LQR}): it would hold its rpm the whole batch; give a target on s_mean_um (an LQR tracks a "
                      "moment: a D-value target is for the MPC)")
    assert not d.exists()
