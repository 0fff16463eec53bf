"""A mistyped key is named as the typo, with the known key it is close to, before anything is called
missing; `card show --rpm` refuses empty entries and speeds too slow to mill."""

import pytest

from bmctl.config import Schedule, validate
from bmctl.errors import InputError

from tests.config.test_strict_inputs import LAB, mutated, one_line_error


@pytest.mark.parametrize("old, new, needle", [
    ("alpha = 2.1", "alpah = 2.1", "card.toml: stochastic.alpah: unknown field (did you mean alpha?)"),
    ("sun_radius_m = 0.07", "sun_raduis_m = 0.07",
     "card.toml: mill.sun_raduis_m: unknown field (did you mean sun_radius_m?)"),
    ("[stochastic]", "[stochastik]", "card.toml: [stochastik]: unknown table (did you mean [stochastic]?)"),
    ("[powder]", "[powdr]", "card.toml: [powdr]: unknown table (did you mean [powder]?)"),
])
def test_a_mistyped_card_key_is_named_with_the_close_known_one(tmp_path, capsys, old, new, needle):
    p = mutated(tmp_path, LAB, old, new)
    line = one_line_error(capsys, ["card", "show", p], needle)
    assert "missing" not in line and line.endswith(needle)


def test_a_mistyped_schedule_key_is_named_not_reported_missing(tmp_path, capsys):
    p = tmp_path / "sched.toml"
    p.write_text("[[segment]]\nhours = 2\nrmp = 300\n", encoding="utf-8")
    out = tmp_path / "out"
    line = one_line_error(capsys, ["simulate", LAB, "--schedule", p, "--out", out, "--no-progress"],
                          "sched.toml: segment[0].rmp: unknown field (did you mean rpm?)")
    assert line.endswith("(did you mean rpm?)") and not out.exists()  # the missing rpm is the same typo
    with pytest.raises(InputError, match=r"^s: segment\[0\]\.hurs: unknown field \(did you mean hours\?\) "
                                         r"\(\+1 more problem\)$"):
        validate(Schedule, {"segment": [{"hurs": 1.0, "rpm": -1.0}]}, "s")
    with pytest.raises(InputError, match=r"^s: segment\[0\]\.colour: unknown field$"):  # nothing close: no guess
        validate(Schedule, {"segment": [{"hours": 1.0, "rpm": 300.0, "colour": 1}]}, "s")


@pytest.mark.parametrize("rpm", [",300", "300,,400", "300,", "1e-9", "0.5"])
def test_card_show_refuses_an_empty_entry_or_a_speed_below_1_rpm(tmp_path, capsys, rpm):
    line = one_line_error(capsys, ["card", "show", LAB, "--rpm", rpm], "--rpm: ")
    assert ("empty entry" in line) if "," in rpm else ("below 1 rpm" in line)


def test_card_show_prints_the_speed_it_computed(capsys):
    from bmctl.cli import main

    assert main(["card", "show", str(LAB), "--rpm", "299.6,300"]) == 0
    rows = [ln.split()[0] for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("299.")
            or ln.strip().startswith("300 ")]
    assert rows == ["299.6", "300"]


@pytest.mark.parametrize("old, new, needle", [
    ("[temperature]", "[temperatur]", "temperatur: unknown table (did you mean [temperature]?)"),
    ("ceiling_c = 80.0", "ceilin_c = 80.0", "temperature.ceilin_c: unknown field (did you mean ceiling_c?)"),
])
def test_a_mistyped_controller_table_is_called_a_table(tmp_path, capsys, old, new, needle):
    from pathlib import Path

    ctl = mutated(tmp_path, Path(__file__).parents[2] / "controllers" / "mpc-default.toml", old, new)
    line = one_line_error(capsys, ["design", LAB, "--controller", ctl, "--target", "s_mean_um=30",
                                   "--out", tmp_path / "o"], needle)
    assert line.endswith(needle) and not (tmp_path / "o").exists()


def test_a_mistyped_nested_table_hint_names_its_parent():
    from bmctl.config import unknown_key_message

    assert unknown_key_message("pff", ["pf", "kind"], table=True, parent="estimator") == \
        "unknown table (did you mean [estimator.pf]?)"
