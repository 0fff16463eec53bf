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
    assert {k: LIBRARY_FLAGS[k] for k in ("um_per_px", "scale_bar_um", "identify=True")} == {
        "um_per_px": "--um-per-px", "scale_bar_um": "--scale-bar-um", "identify=True": "--identify"}
    with naming(LIBRARY_FLAGS):
        assert [arg(a) for a in ("um_per_px", "scale_bar_um", "identify=True", "hours")] == [*FLAGS, "hours"]
    assert arg("identify=True") == "identify=True"


# --- the measurement's own arguments: min_particles, min_area_px, crop (bmctl.measure) ----------------

def test_measurement_arguments_are_named_as_python_spells_them(plain):
    from bmctl.measure.loading import parse_crop

    img = np.asarray(Image.open(plain), dtype=float) / 255.0
    msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, min_particles=-1))
    assert msg == "min_particles: expected a whole number >= 0 (got -1)", msg
    msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, min_area_px="big"))
    assert msg == "min_area_px: expected a number of px or 'auto' (got 'big')", msg
    msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, crop="a:b"))
    assert msg == "crop: expected Y0:Y1,X0:X1 in pixels (got 'a:b')", msg
    msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, crop="10:5,0:20"))
    assert msg == "crop: empty window '10:5,0:20' (need Y0 < Y1 and X0 < X1)", msg
    assert _refusal(lambda: parse_crop("0:0,:")).startswith("crop: empty window")
    assert "--" not in _refusal(lambda: measure_micrograph(img, um_per_px=1.0, crop="x"))


def test_measurement_arguments_from_the_command_name_the_flags(plain, capsys):
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "1", "--crop", "a:b"])
    assert line == "bmctl: error: --crop: expected Y0:Y1,X0:X1 in pixels (got 'a:b')", line
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "1", "--crop", "10:5,0:20"])
    assert line == "bmctl: error: --crop: empty window '10:5,0:20' (need Y0 < Y1 and X0 < X1)", line
    # the command checks --min-particles and --min-area-px itself; the library, run as the command runs it,
    # names the same flags
    from bmctl.commands._args import LIBRARY_FLAGS

    img = np.asarray(Image.open(plain), dtype=float) / 255.0
    with naming(LIBRARY_FLAGS):
        msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, min_particles=-1))
        assert msg == "--min-particles: expected a whole number >= 0 (got -1)", msg
        msg = _refusal(lambda: measure_micrograph(img, um_per_px=1.0, min_area_px="big"))
        assert msg == "--min-area-px: expected a number of px or 'auto' (got 'big')", msg
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "1", "--min-particles", "-1"])
    assert line == "bmctl: error: --min-particles: must be >= 0 (got -1)", line
    line = _cli_error(capsys, ["measure", plain, "--um-per-px", "1", "--min-area-px", "big"])
    assert line == "bmctl: error: --min-area-px: expected a number of px or 'auto' (got 'big')", line
    assert _refusal(lambda: measure_micrograph(img, um_per_px=1.0, crop="a:b")).startswith("crop: ")


# --- the sample's time against the schedule (bmctl.measure.compare) ----------------------------------

def test_compare_time_is_named_as_python_spells_it():
    from bmctl.measure.compare import predicted_population, truncate_schedule

    msg = _refusal(lambda: truncate_schedule([(2.0, 300.0)], 5.0))
    assert msg == "at_h: must be in [0, 2] h, the schedule's length (got 5)", msg
    from bmctl.config import load_card

    msg = _refusal(lambda: predicted_population(load_card(CARD), [(2.0, 300.0)], -1.0, np.random.default_rng(0), 100))
    assert msg.startswith("at_h: must be in [0, 2] h"), msg


def test_compare_command_names_the_at_h_flag(tmp_path, capsys):
    from bmctl.measure.compare import truncate_schedule

    t = tmp_path / "t.csv"
    t.write_text("s_um,r\n40,0.1\n50,0.2\n60,0.1\n", encoding="utf-8")
    line = _cli_error(capsys, ["compare", t, "--model", CARD, "--at-h", "99", "--out", tmp_path / "o"])
    assert line.startswith("bmctl: error: --at-h: must be in [0, "), line
    assert line.endswith("h, the schedule's length (got 99)"), line
    assert not (tmp_path / "o").exists()
    assert _refusal(lambda: truncate_schedule([(2.0, 300.0)], 5.0)).startswith("at_h: ")


# --- the start of an identification (bmctl.moments.forcard.identification) ---------------------------

@pytest.fixture
def unfingerprinted(tmp_path) -> Path:
    """The lab's coefficient file without its [card] table (a file from before fingerprints)."""
    text = cf.coeffs_path(CARD).read_text(encoding="utf-8")
    p = tmp_path / "old.moments.toml"
    p.write_text(text[:text.index("[card]")] + text[text.index("[window]"):], encoding="utf-8")
    return p


def test_identification_start_is_named_as_python_spells_it(unfingerprinted):
    from bmctl.config import load_card
    from bmctl.moments.forcard import identification

    msg = _refusal(lambda: identification(load_card(CARD), CARD, start=unfingerprinted))
    assert msg == f"start: {unfingerprinted}: records no card fingerprint; give an identified file", msg


def test_identify_command_names_the_start_flag(unfingerprinted, tmp_path, capsys):
    from bmctl.config import load_card
    from bmctl.moments.forcard import identification

    line = _cli_error(capsys, ["identify", CARD, "--start", unfingerprinted, "--quick", "--workers", "0",
                               "--out", tmp_path / "x.moments.toml"])
    assert line == f"bmctl: error: --start: {unfingerprinted}: records no card fingerprint; give an identified file"
    assert not (tmp_path / "x.moments.toml").exists()
    assert _refusal(lambda: identification(load_card(CARD), CARD, start=unfingerprinted)).startswith("start: ")


def test_the_added_names_are_those_the_functions_take():
    from bmctl.commands._args import LIBRARY_FLAGS
    from bmctl.measure.compare import predicted_population, truncate_schedule
    from bmctl.moments.forcard import identification

    assert {"min_particles", "min_area_px", "crop"} <= set(inspect.signature(measure_micrograph).parameters)
    assert "at_h" in inspect.signature(truncate_schedule).parameters
    assert "at_h" in inspect.signature(predicted_population).parameters
    assert "start" in inspect.signature(identification).parameters
    added = {"min_particles": "--min-particles", "min_area_px": "--min-area-px", "crop": "--crop",
             "at_h": "--at-h", "start": "--start"}
    assert {k: LIBRARY_FLAGS.get(k) for k in added} == added
    assert cp_flags()["at_h"] == LIBRARY_FLAGS["at_h"]  # campaign sample passes at_h as the same flag


def cp_flags() -> dict:
    from bmctl.commands.campaign import FLAGS as CAMPAIGN_FLAGS

    return CAMPAIGN_FLAGS


# --- a trial run as a campaign into a used folder (bmctl.campaign.simulated) -------------------------

def _used_trial_folder(tmp_path) -> tuple[Path, Path]:
    from .campaign.scenarios import lqr_scenario

    s = lqr_scenario(tmp_path / "sc.toml")
    out = tmp_path / "t"
    out.mkdir()
    (out / "trajectory.csv").write_text("k\n", encoding="utf-8")
    return s, out


def test_trial_as_campaign_names_out_as_python_spells_it(tmp_path):
    from bmctl.campaign.simulated import run_trial_as_campaign

    s, out = _used_trial_folder(tmp_path)
    msg = _refusal(lambda: run_trial_as_campaign(s, out))
    assert msg == (f"out: {out} already holds a trial; give another folder (a trial run as a campaign "
                   "does not resume)"), msg


def test_trial_command_with_campaign_names_the_out_flag(tmp_path, capsys):
    from bmctl.campaign.simulated import run_trial_as_campaign

    s, out = _used_trial_folder(tmp_path)
    line = _cli_error(capsys, ["trial", s, "--campaign", "--out", out, "--no-progress"])
    assert line == (f"bmctl: error: --out: {out} already holds a trial; give another folder (a trial run as a "
                    "campaign does not resume)"), line
    assert _refusal(lambda: run_trial_as_campaign(s, out)).startswith("out: ")
    assert not (out / "campaign").exists()


# --- a trial's folder and resumption (bmctl.trial.run_trial) ------------------------------------------

def test_trial_names_out_and_resume_as_python_spells_them(tmp_path):
    from bmctl.trial import run_trial

    assert {"out", "resume", "seed"} <= set(inspect.signature(run_trial).parameters)
    s, out = _used_trial_folder(tmp_path)
    msg = _refusal(lambda: run_trial(s, out))
    assert msg == f"out: {out} already holds a trial; use resume=True or another folder", msg
    missing = tmp_path / "none"
    msg = _refusal(lambda: run_trial(s, missing, resume=True))
    assert msg == f"resume=True: {missing / 'trial.json'} not found", msg


def test_trial_command_names_the_out_and_resume_flags(tmp_path, capsys):
    s, out = _used_trial_folder(tmp_path)
    line = _cli_error(capsys, ["trial", s, "--out", out, "--no-progress"])
    assert line == f"bmctl: error: --out: {out} already holds a trial; use --resume or another folder", line
    missing = tmp_path / "none"
    line = _cli_error(capsys, ["trial", s, "--resume", missing, "--no-progress"])
    assert line == f"bmctl: error: --resume: {missing / 'trial.json'} not found", line


# --- ensemble engines (bmctl.parallel) and calibrated parameters (bmctl.calibrate.params) -------------

def test_engine_and_parameter_arguments_are_named_as_python_spells_them():
    from bmctl.calibrate.params import check_calibratable
    from bmctl.calibrate.run import run_calibration
    from bmctl.config import load_card
    from bmctl.control.design import plant_check
    from bmctl.parallel import check_engine_args, client_for

    assert {"workers", "scheduler"} <= set(inspect.signature(plant_check).parameters)
    assert {"workers", "scheduler"} <= set(inspect.signature(client_for).parameters)
    assert "names" in inspect.signature(run_calibration).parameters
    assert _refusal(lambda: client_for(workers=-1)) == "workers: must be >= 0 (got -1)"
    assert _refusal(lambda: check_engine_args(2, "tcp://h:8786")) == (
        "workers: sets the local Dask workers, which scheduler replaces")
    assert _refusal(lambda: check_calibratable(load_card(CARD), "process.rpm")).startswith(
        "names: process.rpm is an operating setting")


def test_engine_and_parameter_flags_from_the_commands(tmp_path, capsys):
    from bmctl.commands._args import LIBRARY_FLAGS
    from bmctl.parallel import client_for

    with naming(LIBRARY_FLAGS):
        assert _refusal(lambda: client_for(workers=-1)) == "--workers: must be >= 0 (got -1)"
    schedule = ROOT / "scenarios" / "schedule-lab-300rpm-12h.toml"
    line = _cli_error(capsys, ["whatif", CARD, schedule, "--workers", "2", "--scheduler", "tcp://h:8786",
                               "--out", tmp_path / "w"])
    assert line == "bmctl: error: --workers: sets the local Dask workers, which --scheduler replaces", line
    history = tmp_path / "h.toml"
    history.write_text('[[segment]]\nhours = 1.0\nrpm = 300.0\n', encoding="utf-8")
    line = _cli_error(capsys, ["calibrate", CARD, history, "--params", "process.rpm", "--workers", "0",
                               "--out", tmp_path / "c"])
    assert line.startswith("bmctl: error: --params: process.rpm is an operating setting"), line


def test_resuming_a_trial_run_as_a_campaign_is_named_as_the_caller_spells_it(tmp_path, capsys):
    """The folder of a trial run as a campaign does not resume: from Python the message names
    resume=True, seed and out; from the command --resume, --seed and --out."""
    import json as _json

    from bmctl.trial import run_trial

    s, out = _used_trial_folder(tmp_path)
    (out / "trial.json").write_text(_json.dumps({"campaign": True, "scenario": str(s), "seed": 0}), encoding="utf-8")
    msg = _refusal(lambda: run_trial(s, out, resume=True))
    assert msg == (f"resume=True: {out} holds a trial run as a campaign, which does not resume; run it again with "
                   "the same seed into a new out"), msg
    line = _cli_error(capsys, ["trial", s, "--resume", out, "--no-progress"])
    assert line == (f"bmctl: error: --resume: {out} holds a trial run as a campaign, which does not resume; run it "
                    "again with the same --seed into a new --out"), line
