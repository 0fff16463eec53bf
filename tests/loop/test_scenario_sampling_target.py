"""Scenario checks: a sampling setting the rendered path does not use, and target values out of
range named by the key alone (not by the members of the number-or-window type)."""

import re
import tomllib

import pytest

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.scenario import load_scenario

from ..conftest import ROOT

SCENARIO = """
model = "{root}/models/alni-1to1-300rpm-lab.toml"
hours = 1
target = {{ s_mean_um = {target} }}
[scenario]
name = "small"
description = "one hour of MPC"
[sampling]
{sampling}
[controller]
config = "{root}/controllers/mpc-fast.toml"
"""


def _scenario(tmp_path, sampling="", target="50.0"):
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(root=ROOT, sampling=sampling, target=target), encoding="utf-8")
    return path


def test_noise_with_render_is_refused_naming_the_field(tmp_path, capsys):
    """micrograph_sample passes noise to the fast path only: with render = true it did nothing."""
    sc = _scenario(tmp_path, "render = true\nnoise = 0.1")
    with pytest.raises(InputError, match=r"s\.toml: sampling\.noise: used only without render"):
        load_scenario(sc)
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sampling.noise: used only without render" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    # the default given explicitly does nothing either; each setting alone is used
    with pytest.raises(InputError, match=r"sampling\.noise"):
        load_scenario(_scenario(tmp_path, "render = true\nnoise = 0.03"))
    assert load_scenario(_scenario(tmp_path, "render = true")).sampling.render
    assert load_scenario(_scenario(tmp_path, "noise = 0.1")).sampling.noise == 0.1


@pytest.mark.parametrize("target, said", [
    ("0.0", "target.s_mean_um: Input should be greater than 0 (got 0.0)"),
    ("[0.0, 2.0]", "target.s_mean_um[0]: Input should be greater than 0 (got 0.0)"),
    ('"big"', "target.s_mean_um: Input should be a valid number or a valid list (got 'big')"),
])
def test_a_target_value_out_of_range_names_the_key(tmp_path, capsys, target, said):
    sc = _scenario(tmp_path, target=target)
    with pytest.raises(InputError, match=re.escape(f"{sc}: {said}") + "$"):
        load_scenario(sc)
    assert main(["trial", str(sc), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert capsys.readouterr().err == f"bmctl: error: {sc}: {said}\n"


def test_other_errors_and_their_count_are_kept():
    """Two keys out of range are two problems; errors outside a union pass unchanged."""
    from bmctl.config import merge_union_errors

    e = [{"type": "greater_than", "loc": ("target", "a", "constrained-float"), "msg": "m1", "input": 0.0},
         {"type": "list_type", "loc": ("target", "a", "list[constrained-float]"), "msg": "m2", "input": 0.0},
         {"type": "greater_than", "loc": ("target", "b", "constrained-float"), "msg": "m3", "input": 0.0},
         {"type": "list_type", "loc": ("target", "b", "list[constrained-float]"), "msg": "m4", "input": 0.0},
         {"type": "missing", "loc": ("controller",), "msg": "Field required", "input": {}}]
    assert [(x["loc"], x["msg"]) for x in merge_union_errors(e)] == [
        (("target", "a"), "m1"), (("target", "b"), "m3"), (("controller",), "Field required")]
    assert merge_union_errors(e[4:]) == e[4:]


def test_a_controller_files_target_is_named_by_its_key_too(tmp_path):
    """The same merge applies to every config file (a controller's [target] is a union too)."""
    from bmctl.control.config import load_controller

    src = (ROOT / "controllers" / "mpc-fast.toml").read_text(encoding="utf-8")
    assert "target" not in tomllib.loads(src)  # its "# [target]" is a comment: the table is added here
    bad = tmp_path / "c.toml"
    bad.write_text(src + '\n[target]\ns_mean_um = "a"\n', encoding="utf-8")
    with pytest.raises(InputError) as exc:
        load_controller(bad)
    text = str(exc.value)
    assert "target.s_mean_um:" in text and "float" not in text.split(":")[1], text
