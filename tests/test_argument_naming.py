"""Refusals name what the caller gave: from Python the argument as the function takes it
(``um_per_px``, ``scale_bar_um``, ``identify=True``), from a command its flag (``--um-per-px``,
``--scale-bar-um``, ``--identify``), through :func:`bmctl.naming.arg` and :func:`bmctl.naming.naming`.

Three places: the pixel size of a micrograph (:mod:`bmctl.measure.scale`), the table check that
advises checking the scale (:func:`bmctl.measure.tables.check_table`) and the refusal of a card
without its own moment coefficients (:func:`bmctl.moments.for_card`)."""

from __future__ import annotations

import inspect
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bmctl import campaign as cp
from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.micrograph import measure_micrograph
from bmctl.measure.scale import check_scale, resolve_scale
from bmctl.measure.tables import ParticleTable, check_table
from bmctl.moments import coeffs as cf
from bmctl.moments.forcard import for_card
from bmctl.naming import arg, naming

from .measure.shapes import discs

ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
FLAGS = ("--um-per-px", "--scale-bar-um", "--identify")


def _refusal(call) -> str:
    with pytest.raises(InputError) as e:
        call()
    return str(e.value)


def _cli_error(capsys, argv) -> str:
    """``bmctl ARGV``'s one error line (exit status 2)."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, (rc, err)
    assert err[0].startswith("bmctl: error: "), err
    return err[0]


def _no_flag(msg: str) -> None:
    assert not any(f in msg for f in FLAGS), msg


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    """A micrograph with no pixel size in its metadata and no scale bar: nine discs, 128 x 128 px."""
    p = tmp_path_factory.mktemp("naming") / "plain.png"
    Image.fromarray(discs()).save(p)
    return p


@pytest.fixture(scope="module")
def bar_image(tmp_path_factory) -> Path:
    """A plain image with a 50 px scale bar in its bottom quarter (no metadata)."""
    img = np.full((200, 200), 0.8)
    img[170:173, 50:100] = 0.0
    p = tmp_path_factory.mktemp("naming") / "bar.png"
    Image.fromarray(np.round(img * 255).astype(np.uint8)).save(p)
    return p


@pytest.fixture
def foreign(tmp_path) -> Path:
    """The lab card with one fingerprinted field changed, next to the lab's coefficient file."""
    p = tmp_path / "card.toml"
    p.write_text(CARD.read_text(encoding="utf-8").replace("ball_count = 10", "ball_count = 12"), encoding="utf-8")
    shutil.copyfile(cf.coeffs_path(CARD), cf.coeffs_path(p))
    return p


# --- the pixel size (bmctl.measure.scale) ------------------------------------------------------------

def test_scale_messages_name_the_python_arguments(plain, bar_image):
    img = np.asarray(Image.open(plain), dtype=float) / 255.0
    msg = _refusal(lambda: measure_micrograph(img))
    assert msg.startswith("image: no pixel size in the image metadata; give the scale with um_per_px X, "
                          "or scale_bar_um L"), msg
    _no_flag(msg)
    msg = _refusal(lambda: measure_micrograph(str(plain)))
    assert "um_per_px X" in msg and "scale_bar_um L" in msg, msg
    _no_flag(msg)
    msg = _refusal(lambda: measure_micrograph(img, scale_bar_um=5.0))
    assert msg == "image: scale_bar_um given but no scale bar found; give the scale with um_per_px X", msg
    msg = _refusal(lambda: measure_micrograph(img, um_per_px=-1.0))
    assert msg.startswith("um_per_px: must be a finite number > 0"), msg
    msg = _refusal(lambda: measure_micrograph(img, scale_bar_um=1e9))
    assert msg.startswith("scale_bar_um: 1e+09 µm is outside the sane range [0.001, 100000] µm"), msg
    bar = np.asarray(Image.open(bar_image), dtype=float) / 255.0
    msg = _refusal(lambda: resolve_scale(None, bar, scale_bar_um=1e5))
    assert "pixel size from the scale bar, 2000 µm/px" in msg and "(scale_bar_um)" in msg, msg
    assert msg.endswith("; check scale_bar_um, or give the scale with um_per_px X"), msg
    _no_flag(msg)
    assert check_scale(2e4, "scale_bar_um") == 2e4  # a bar length has its own range
    assert _refusal(lambda: check_scale(2e4)).startswith("um_per_px: 20000 µm is outside")


def test_scale_messages_from_the_command_name_the_flags(plain, bar_image, capsys):
    line = _cli_error(capsys, ["measure", plain])
    assert line == (f"bmctl: error: {plain}: no pixel size in the image metadata; give the scale with --um-per-px X, "
                    "or --scale-bar-um L (the length written on the image's scale bar)"), line
    line = _cli_error(capsys, ["measure", plain, "--scale-bar-um", "5"])
    assert line == f"bmctl: error: {plain}: --scale-bar-um given but no scale bar found; give the scale with --um-per-px X"
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "-1"])
    assert line.startswith("bmctl: error: --um-per-px: must be a finite number > 0"), line
    line = _cli_error(capsys, ["measure", plain, "--scale-bar-um", "1e9"])
    assert line.startswith("bmctl: error: --scale-bar-um: 1e+09 µm is outside the sane range [0.001, 100000] µm")
    line = _cli_error(capsys, ["measure", bar_image, "--scale-bar-um", "100000"])
    assert "µm (--scale-bar-um)); check --scale-bar-um, or give the scale with --um-per-px X" in line, line
    # a Python call after the command names its argument again
    assert _refusal(lambda: measure_micrograph(str(plain))).count("um_per_px X") == 1
    assert arg("um_per_px") == "um_per_px"


def test_the_recorded_scale_source_is_the_same_from_python_and_the_command(plain, tmp_path, capsys):
    """``measure.json`` keeps what it always recorded for a given pixel size: ``--um-per-px``."""
    rep = measure_micrograph(str(plain), um_per_px=0.5).report()
    assert rep["scale"] == {"um_per_px": 0.5, "source": "user", "detail": "--um-per-px"}
    assert main(["measure", str(plain), "--um-per-px", "0.5", "--out", str(tmp_path / "t.csv")]) == 0
    capsys.readouterr()
    doc = json.loads((tmp_path / "measure.json").read_text(encoding="utf-8"))
    assert doc["inputs"][0]["scale"] == rep["scale"]


# --- the table check (bmctl.measure.tables.check_table) ----------------------------------------------

def test_table_check_names_the_python_arguments():
    t = ParticleTable.from_area_perimeter([np.pi * 1e8], [2 * np.pi * 1e4 * 1.1])  # s = 20000 µm
    msg = _refusal(lambda: check_table(t, "t.csv"))
    assert msg.startswith("t.csv: particle 1: s_um = 2e+04 outside [0.001, 10000] µm"), msg
    assert msg.endswith("check the scale (um_per_px, scale_bar_um)"), msg
    _no_flag(msg)


def test_table_check_from_the_command_names_the_flags(plain, capsys):
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "1000"])
    assert line.startswith(f"bmctl: error: {plain}: particle 1: s_um = "), line
    assert line.endswith("check the scale (--um-per-px, --scale-bar-um)"), line


# --- a card without its own coefficients (bmctl.moments.for_card) ------------------------------------

def test_for_card_names_identify_true(foreign, tmp_path):
    msg = _refusal(lambda: for_card(foreign))
    assert msg.endswith(f"fix: bmctl identify {foreign} (about a minute), or add identify=True"), msg
    _no_flag(msg)
    msg = _refusal(lambda: cp.init(tmp_path / "c", foreign, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100))
    assert msg.endswith("or add identify=True"), msg
    _no_flag(msg)


@pytest.mark.parametrize("argv", [
    ["design", "{card}", "--target", "s_mean_um=30", "--out", "{out}"],
    ["linearize", "{card}", "--out", "{out}"],
    ["estimate", "{card}", "--samples", "{sample}", "--times", "1", "--out", "{out}/e.csv"],
    ["campaign", "init", "{out}", "--model", "{card}", "--controller", str(RECIPE), "--target", "d50_um=45"],
], ids=lambda a: a[0] if a[0] != "campaign" else "campaign-init")
def test_commands_name_the_identify_flag(argv, foreign, tmp_path, capsys):
    sample = tmp_path / "s.csv"
    sample.write_text("s_um,r\n" + "".join(f"{40 + k % 7},{0.01 * (k % 5)}\n" for k in range(60)), encoding="utf-8")
    line = _cli_error(capsys, [a.format(card=foreign, out=tmp_path / "out", sample=sample) for a in argv])
    assert line.endswith(f"fix: bmctl identify {foreign} (about a minute), or add --identify"), line
    assert "identify=True" not in line


def test_trial_names_the_identify_flag(foreign, tmp_path, capsys):
    from .campaign.scenarios import lqr_scenario

    s = lqr_scenario(tmp_path / "sc.toml")
    s.write_text(s.read_text(encoding="utf-8").replace(str(CARD), str(foreign)), encoding="utf-8")
    line = _cli_error(capsys, ["trial", s, "--out", tmp_path / "t", "--no-progress"])
    assert line.endswith("or add --identify"), line


# --- a campaign sample: the verb and the command ------------------------------------------------------

@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("naming") / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    return d


def test_campaign_sample_of_an_unscaled_image(campaign, plain, capsys):
    msg = _refusal(lambda: cp.sample(campaign, 0.5, [plain]))
    assert msg.startswith(f"{plain}: no pixel size in the image metadata; give the scale with um_per_px X"), msg
    _no_flag(msg)
    line = _cli_error(capsys, ["campaign", "sample", campaign, "--at-h", "0.5", plain])
    assert line == (f"bmctl: error: {plain}: no pixel size in the image metadata; give the scale with --um-per-px X, "
                    "or --scale-bar-um L (the length written on the image's scale bar)"), line
    assert cp.status(campaign)["counts"]["samples"] == 0


# --- the names are the functions' own ----------------------------------------------------------------

def test_the_named_arguments_are_those_the_functions_take():
    from bmctl.commands._args import LIBRARY_FLAGS

    takes = set(inspect.signature(measure_micrograph).parameters) & set(inspect.signature(resolve_scale).parameters)
    assert {"um_per_px", "scale_bar_um"} <= takes
    assert "identify" in inspect.signature(for_card).parameters
    assert "identify" in inspect.signature(cp.init).parameters and "um_per_px" in inspect.signature(cp.sample).parameters
    assert LIBRARY_FLAGS == {"um_per_px": "--um-per-px", "scale_bar_um": "--scale-bar-um", "identify=True": "--identify"}
    with naming(LIBRARY_FLAGS):
        assert [arg(a) for a in ("um_per_px", "scale_bar_um", "identify=True", "hours")] == [*FLAGS, "hours"]
    assert arg("identify=True") == "identify=True"
