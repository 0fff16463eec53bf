"""The Python API's campaign and controller entry points take numbers as numbers and name their
arguments: a campaign target ``{"d50_um": "55"}`` or a controller's ``set_target({"s_mean_um": "25"},
t_end_h="3")`` is a one-line InputError naming the argument and key (the text was read as 55 and 25,
and ``t_end_h`` raised a TypeError); ``init`` given its target as text names ``target``, not the
command's ``--target``; the verbs' other numbers (``log(rpm="300")``, ``hours=True``) are refused
too. The command still parses ``--target`` text. A plan's ``u_apply`` and
``applied()`` are documented as what they are: the input to run now, and a preview of the plan whose
first row can differ. Valid inputs give the same targets as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.cli import main
from bmctl.control import Plan, make_controller
from bmctl.control.base import Reference
from bmctl.errors import InputError
from bmctl.moments import make_moment_model

ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
MPC = ROOT / "controllers" / "mpc-default.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"


def _init(d, target, ctrl=RECIPE):
    return cp.init(d, CARD, ctrl, target, hours=2.0, particles=50)


@pytest.fixture(scope="module")
def model():
    return make_moment_model(CARD)


@pytest.fixture
def lqr(model):
    return make_controller(str(LQR), model)


# --- a campaign's target from Python ------------------------------------------------------------
@pytest.mark.parametrize("value", ["55", b"55", True, np.bool_(True)])
def test_init_refuses_a_target_value_that_is_not_a_number(tmp_path, value):
    d = tmp_path / "c"
    with pytest.raises(InputError, match=r"^target: d50_um: not a number: ") as exc:
        _init(d, {"d50_um": value})
    assert "\n" not in str(exc.value)
    assert not d.exists()  # refused before anything is written


def test_a_number_given_as_text_shows_both_forms(tmp_path):
    with pytest.raises(InputError, match=r"""not a number: '55' \(give the number 55, or the whole target as """
                                         r"""text: "d50_um=55"\)$"""):
        _init(tmp_path / "c", {"d50_um": "55"})


def test_init_refuses_a_window_as_a_window(tmp_path):
    with pytest.raises(InputError, match=r"^target: d50_um: a campaign takes one value per target, not a window"):
        _init(tmp_path / "c", {"d50_um": [40.0, 50.0]})


@pytest.mark.parametrize("target", [45.0, None])
def test_init_refuses_a_target_that_is_no_mapping(tmp_path, target):
    with pytest.raises(InputError, match=r"^target: expected a dict such as"):
        _init(tmp_path / "c", target)


@pytest.mark.parametrize("text,needle", [("d50_um=45,x=3", "unknown target 'x'"), ("", "empty target"),
                                         ("d50_um=abc", "d50_um: not a number")])
def test_init_given_its_target_as_text_names_the_argument(tmp_path, text, needle):
    with pytest.raises(InputError) as exc:
        _init(tmp_path / "c", text)
    assert str(exc.value).startswith(f"target: {needle}"), exc.value  # not the command's --target


def test_init_without_a_target_names_the_argument(tmp_path):
    with pytest.raises(InputError, match=r"^target: a feedback controller \(mpc\) needs a target"):
        _init(tmp_path / "c", {}, ctrl=MPC)


@pytest.mark.parametrize("target", [{"d50_um": 45}, {"d50_um": np.float64(45.0)}, [("d50_um", 45.0)], "d50_um=45"])
def test_valid_targets_are_taken_as_before(tmp_path, target):
    meta = _init(tmp_path / "c", target)
    assert meta["target"] == {"d50_um": 45.0} and type(meta["target"]["d50_um"]) is float


def test_the_command_still_parses_its_target_text(tmp_path, capsys):
    d = tmp_path / "c"
    args = ["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE), "--hours", "2",
            "--particles", "50", "--target"]
    assert main(args + ["d50_um=55"]) == 0
    assert cp.status(d)["target"] == {"d50_um": 55.0}
    capsys.readouterr()
    assert main([*args[:2], str(tmp_path / "e"), *args[3:], "d50_um=abc"]) == 2
    err = capsys.readouterr().err
    assert err == "bmctl: error: --target: d50_um: not a number: 'abc'\n", err  # the flag, as before
    assert not (tmp_path / "e").exists()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("api") / "c"
    _init(d, {"d50_um": 45.0})
    return d


@pytest.mark.parametrize("verb,kw,name", [
    ("log", {"rpm": "300", "hours": 0.5}, "rpm"), ("log", {"rpm": 300.0, "hours": True}, "hours"),
    ("log", {"rpm": 300.0, "hours": 0.5, "milling": "1"}, "milling"),
    ("log", {"rpm": 300.0, "hours": 0.5, "temperature_c": b"40"}, "temperature_c"),
    ("log", {"rpm": 300.0, "hours": 0.5, "from_h": "0"}, "from_h"),
    ("sample", {"at_h": "0.5", "inputs": [ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"]}, "at_h"),
    ("decide", {"accept": False, "rpm": "250"}, "rpm")])
def test_verbs_refuse_numbers_given_as_text_or_flags(campaign, verb, kw, name):
    """The verbs read ``"300"`` as 300 and ``hours=True`` as one hour; nothing is recorded now."""
    with pytest.raises(InputError, match=rf"^{name}: not a number \("):
        getattr(cp, verb)(campaign, **kw)
    assert cp.status(campaign)["counts"]["actions"] == 0 and cp.status(campaign)["counts"]["samples"] == 0


@pytest.mark.parametrize("kw,name", [({"hours": "2"}, "hours"), ({"temperature_max_c": True}, "temperature_max_c")])
def test_init_refuses_numbers_given_as_text_or_flags(tmp_path, kw, name):
    d = tmp_path / "c"
    with pytest.raises(InputError, match=rf"^{name}: not a number \("):
        cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, **{"hours": 2.0, "particles": 50, **kw})
    assert not d.exists()


# --- a controller's target and batch end from Python --------------------------------------------
@pytest.mark.parametrize("value", ["25", b"25", ["20", "30"], [20.0, "30"]])
def test_set_target_refuses_text(lqr, value):
    with pytest.raises(InputError, match=r"^target: s_mean_um: not a number: "):
        lqr.set_target({"s_mean_um": value})


def test_a_time_varying_target_refuses_text(lqr):
    with pytest.raises(InputError, match=r"^target: from_h: not a number: '1'"):
        lqr.set_target([(0.0, {"s_mean_um": 30.0}), ("1", {"s_mean_um": 25.0})])
    lqr.set_target(lambda t_h: {"s_mean_um": "25"})
    with pytest.raises(InputError, match=r"^target: s_mean_um: not a number: '25'"):
        lqr.reference.at(0.0)


@pytest.mark.parametrize("t_end_h", ["3", True, [1.0, 2.0]])
def test_set_target_refuses_a_batch_end_that_is_not_a_number(lqr, t_end_h):
    with pytest.raises(InputError, match=r"^t_end_h: must be a finite number > 0 \(got "):
        lqr.set_target({"s_mean_um": 25.0}, t_end_h=t_end_h)


def test_valid_controller_targets_are_taken_as_before(lqr):
    lqr.set_target({"s_mean_um": 25}, t_end_h=np.float64(6.0))
    assert lqr.reference.points == [(0.0, {"s_mean_um": 25.0})] and lqr.t_end_h == 6.0
    ref = Reference([(1, {"s_mean_um": 25.0}), (0, {"s_mean_um": [20, 30], "r_mean": 0.1})])
    assert ref.points == [(0.0, {"s_mean_um": (20.0, 30.0), "r_mean": 0.1}), (1.0, {"s_mean_um": 25.0})]
    lqr.set_target({"s_mean_um": 25.0}, t_end_h=6)
    assert lqr.t_end_h == 6.0


# --- a plan's input to run ----------------------------------------------------------------------
def test_a_plan_documents_which_input_to_run(model, lqr):
    """``u_apply`` is what runs; ``applied()`` previews the plan, its first row before the mill's limits."""
    lqr.set_target({"s_mean_um": 25.0}, t_end_h=6.0)
    plan = lqr.plan(model.x0(), 0.0)
    assert (plan.rpm, plan.milling) == (float(plan.u_apply[0]), float(plan.u_apply[1]))
    assert not np.array_equal(plan.applied()[0], plan.u_apply)  # the rpm dial and the dwell limits act on u_apply
    assert "What to run next is :attr:`u_apply`" in Plan.__doc__ and "*not* always :attr:`u_apply`" in Plan.__doc__
    assert "may differ from :attr:`u_apply`" in Plan.applied.__doc__ and "run :attr:`u_apply`" in Plan.applied.__doc__
