"""A controller whose lowest milling speed is above the mill's top speed (a card with a small
``mill.rpm_max`` under a controller made for a larger mill) is refused when it is built, in one
line naming the field: the plan on operable schedules milled below ``mill.rpm_min_milling``
without a word, and the LQR and the NLP MPC advised 100 rpm to a 90 rpm mill, which the plant
refused in the middle of a trial."""

import re

import pytest

from bmctl.control import load_controller, make_controller
from bmctl.control.base import check_rpm_range
from bmctl.errors import InputError
from bmctl.moments import make_moment_model

from ..conftest import ROOT


class _SmallMill:
    """The lab card's moment model on a mill whose top speed is ``rpm_max``."""

    def __init__(self, model, rpm_max):
        self._model, self.rpm_max = model, float(rpm_max)

    def __getattr__(self, name):
        return getattr(self._model, name)


@pytest.fixture(scope="module")
def model():
    return make_moment_model(str(ROOT / "models" / "alni-1to1-300rpm-lab.toml"))


@pytest.mark.parametrize("name", ["mpc-default", "mpc-nominal", "lqr-baseline", "lqr-clip"])
def test_a_mill_slower_than_the_lowest_milling_speed_is_refused_naming_the_field(model, name):
    with pytest.raises(InputError, match=rf"^controller {name}: mill\.rpm_min_milling: the lowest milling speed, "
                                         r"100 rpm, is above the card's mill\.rpm_max \(90 rpm\): no speed is left"):
        make_controller(ROOT / "controllers" / f"{name}.toml", _SmallMill(model, 90.0))


@pytest.mark.parametrize("name", ["mpc-default", "mpc-nominal", "lqr-baseline"])
def test_a_mill_whose_top_is_the_lowest_milling_speed_is_kept(model, name):
    ctrl = make_controller(ROOT / "controllers" / f"{name}.toml", _SmallMill(model, 100.0))
    assert ctrl.interval_h == 0.5


def test_the_dial_step_counts():
    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    check_rpm_range(cfg, 105.0)  # 100 rpm is on the 10 rpm dial and under 105
    bounds = cfg.bounds.model_copy(update={"rpm_min": 101.0})
    with pytest.raises(InputError, match=r"bounds\.rpm_min: the lowest milling speed, 110 rpm, is above the card's "
                                         r"mill\.rpm_max \(100 rpm\) on its 10 rpm dial"):
        check_rpm_range(cfg.model_copy(update={"bounds": bounds}), 105.0)


def test_a_recipe_faster_than_the_mill_names_its_controller(model):
    """The refusal said only "rpm: 400 exceeds the mill's rpm_max 90", naming neither file nor controller."""
    with pytest.raises(InputError, match=r"^controller recipe-400rpm-30-10: rpm: 400 exceeds the mill's rpm_max 90 "
                                         r"\(the card's mill\.rpm_max\)$"):
        make_controller(ROOT / "controllers" / "recipe-400rpm-30-10.toml", _SmallMill(model, 90.0))


def test_campaign_init_refuses_a_mill_slower_than_the_lowest_milling_speed(tmp_path, capsys):
    from bmctl.cli import main

    text = (ROOT / "models" / "alni-1to1-300rpm-lab.toml").read_text(encoding="utf-8")
    card = tmp_path / "lab-rpm90.toml"
    card.write_text(text.replace("rpm_max = 600", "rpm_max = 90").replace("rpm = 300", "rpm = 90"), encoding="utf-8")
    assert "rpm_max = 90\n" in card.read_text(encoding="utf-8")
    d = tmp_path / "c"
    assert main(["campaign", "init", str(d), "--model", str(card), "--controller",
                 str(ROOT / "controllers" / "mpc-default.toml"), "--target", "s_mean_um=45"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "mill.rpm_min_milling" in err and "90 rpm" in err
    assert not d.exists()


def _with_rpm_step(tmp_path, step, name="c7.toml"):
    text = (ROOT / "controllers" / "mpc-fast.toml").read_text(encoding="utf-8")
    assert "\nrpm_step = 10.0 " in text
    path = tmp_path / name
    path.write_text(text.replace("\nrpm_step = 10.0 ", f"\nrpm_step = {step} "), encoding="utf-8")
    return path


def test_a_dial_step_above_the_top_speed_is_refused_naming_the_file(tmp_path):
    """mill.rpm_step = 1000 under bounds.rpm_max = 500 leaves only 0 rpm (a rest) on the dial: it was
    refused only when the controller was built, naming bounds.rpm_min and advising "at most 0 rpm"."""
    path = _with_rpm_step(tmp_path, 1000.0)
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: mill\.rpm_step: 1000 rpm is above "
                                         r"bounds\.rpm_max \(500 rpm\): the dial is too coarse.*set mill\.rpm_step "
                                         r"to at most 500 rpm$"):
        load_controller(path)
    assert load_controller(_with_rpm_step(tmp_path, 500.0, "top.toml")).mill.rpm_step == 500.0  # 500 rpm is on it


def test_design_refuses_the_coarse_dial_in_one_line(tmp_path, capsys):
    from bmctl.cli import main

    path = _with_rpm_step(tmp_path, 1000.0)
    out = tmp_path / "d"
    rc = main(["design", str(ROOT / "models" / "alni-1to1-300rpm-lab.toml"), "--target", "d50_um=45",
               "--controller", str(path), "--hours", "0.5", "--plant-seeds", "0", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith(f"bmctl: error: {path}: mill.rpm_step: "), err
    assert not out.exists()


def test_a_dial_step_above_the_cards_top_speed_is_not_told_to_lower_the_bounds_to_0():
    """A 400 rpm dial on a 350 rpm mill: check_rpm_range advised "set bounds.rpm_min and
    mill.rpm_min_milling to at most 0 rpm", which no milling speed satisfies; the step is what is wrong."""
    cfg = load_controller(ROOT / "controllers" / "mpc-fast.toml")
    cfg = cfg.model_copy(update={"mill": cfg.mill.model_copy(update={"rpm_step": 400.0})})
    with pytest.raises(InputError) as exc:
        check_rpm_range(cfg, 350.0)
    msg = str(exc.value)
    assert msg.startswith("controller mpc-fast: mill.rpm_step: the 400 rpm dial is too coarse for this mill"), msg
    assert "the card's mill.rpm_max (350 rpm)" in msg and msg.endswith("set mill.rpm_step to at most 350 rpm")
    assert "at most 0 rpm" not in msg


def test_a_dial_that_leaves_only_rests_is_refused_even_with_zero_lower_bounds():
    """bounds.rpm_min = 0 and mill.rpm_min_milling = 0 with a 400 rpm dial on a 350 rpm mill: both
    ends round to 0 rpm, which passed as a range although no milling speed is left."""
    cfg = load_controller(ROOT / "controllers" / "mpc-fast.toml")
    cfg = cfg.model_copy(update={"mill": cfg.mill.model_copy(update={"rpm_step": 400.0, "rpm_min_milling": 0.0}),
                                 "bounds": cfg.bounds.model_copy(update={"rpm_min": 0.0})})
    with pytest.raises(InputError) as exc:
        check_rpm_range(cfg, 350.0)
    assert "mill.rpm_step: the 400 rpm dial is too coarse" in str(exc.value)
