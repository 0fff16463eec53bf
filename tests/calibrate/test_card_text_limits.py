"""The calibrated card's derived texts fit a card text field (bmctl.config.TEXT_MAX_CHARS).

``bmctl calibrate`` names its histories in ``card.sources`` and both it and ``bmctl estimate
--write-card`` rename the card ``<name>-calibrated``: many or long history paths, or a card name near
the limit, once ended the run in a validation traceback after the work was done.
"""

from __future__ import annotations

import shutil

import pytest

from bmctl.calibrate.outputs import calibrated_card, calibrated_name, calibration_note, fit_text, write_card
from bmctl.cli import main
from bmctl.config import TEXT_MAX_CHARS, load_card

from tests.conftest import ROOT, card_path

LAB = card_path("alni-1to1-300rpm-lab")
FOLDER = "/tmp/hi/cal/lab-notebook-2024-alni-planetary-mill-histories"
RUNS = [f"{FOLDER}/run-{i:02d}-300rpm.toml" for i in range(1, 13)]


def test_a_short_note_names_every_history_as_before():
    assert calibration_note(1, ["a.toml", "b/c.toml"], ["gamma", "delta"]) == (
        "calibrated by bmctl calibrate (seed 1) from a.toml, b/c.toml: gamma, delta")


def test_histories_of_one_folder_are_named_by_it_once():
    old = "calibrated by bmctl calibrate (seed 1) from " + ", ".join(RUNS) + ": gamma, delta"
    assert len(old) > TEXT_MAX_CHARS  # the note that did not fit
    note = calibration_note(1, RUNS, ["gamma", "delta"])
    assert note == (f"calibrated by bmctl calibrate (seed 1) from 12 histories in {FOLDER} ("
                    + ", ".join(f"run-{i:02d}-300rpm.toml" for i in range(1, 13)) + "): gamma, delta")


def test_many_histories_are_counted_past_those_named():
    runs = [f"{FOLDER}/run-{i:03d}-300rpm.toml" for i in range(1, 101)]
    note = calibration_note(1, runs, ["gamma", "delta"])
    assert len(note) <= TEXT_MAX_CHARS
    assert note.startswith(f"calibrated by bmctl calibrate (seed 1) from 100 histories in {FOLDER} "
                           "(run-001-300rpm.toml, run-002-300rpm.toml, ")
    k = note.count("-300rpm.toml")
    assert note.endswith(f", and {100 - k} more, in calibration.json): gamma, delta") and 30 < k < 100
    assert note.count(FOLDER) == 1


def test_a_few_histories_in_one_folder_are_all_named_once_the_folder_is_factored_out():
    paths = [f"{'d' * 350}/run-{i}.toml" for i in range(1, 4)]
    note = calibration_note(0, paths, ["gamma"])
    assert note == (f"calibrated by bmctl calibrate (seed 0) from 3 histories in {'d' * 350} "
                    "(run-1.toml, run-2.toml, run-3.toml): gamma")


@pytest.mark.parametrize("paths", [
    [f"/{'x' * 1200}/h{i}.toml" for i in range(3)],  # the folder alone passes the limit
    [f"/{'x' * 1200}/{'h' * 200}.toml"],  # one history
    [f"/data/{'y' * 240}/{i}/{'h' * 240}.toml" for i in range(40)],  # no common folder of note, long names
    [f"rel/h{i}.toml" for i in range(200)] + [f"/abs/h{i}.toml" for i in range(5)],  # no common folder at all
])
def test_the_note_always_fits(paths):
    note = calibration_note(123, paths, ["alpha", "beta", "gamma", "delta"])
    assert len(note) <= TEXT_MAX_CHARS
    assert note.startswith("calibrated by bmctl calibrate (seed 123) from ")
    assert note.endswith(": alpha, beta, gamma, delta")


def test_calibrated_name_keeps_the_suffix_and_cuts_the_base():
    assert calibrated_name("lab") == "lab-calibrated"
    assert calibrated_name("lab-calibrated") == "lab-calibrated"
    assert calibrated_name("a" * (TEXT_MAX_CHARS - 11)) == "a" * (TEXT_MAX_CHARS - 11) + "-calibrated"
    long = calibrated_name("a" * 995)
    assert len(long) == TEXT_MAX_CHARS and long == "a" * (TEXT_MAX_CHARS - 14) + "...-calibrated"
    assert fit_text("x" * 1500) == "x" * (TEXT_MAX_CHARS - 3) + "..."


def test_a_calibrated_card_of_a_long_name_and_note_is_written_and_loads(tmp_path):
    card = load_card(LAB)
    d = card.model_dump()
    d["card"]["name"] = "b" * 995
    card = type(card).model_validate(d)
    new = calibrated_card(card, ["gamma", "delta"], [2.5e-4, 6e-4], "n" * 1500)
    back = load_card(write_card(tmp_path / "x-calibrated.toml", new))
    assert back.card.name == "b" * (TEXT_MAX_CHARS - 14) + "...-calibrated"
    assert len(back.card.sources[-1]) == TEXT_MAX_CHARS and back.card.sources[-1].endswith("...")
    assert back.stochastic.gamma_per_um2 == 2.5e-4


def test_cli_estimate_write_card_of_a_card_named_near_the_limit(tmp_path, capsys):
    """A 995-character card name: the table and figure were written, then the card's
    ``<name>-calibrated`` failed validation in a traceback. The card is now written, its name cut."""
    card = tmp_path / "long.toml"
    card.write_text((ROOT / "models" / "alni-1to1-300rpm-lab.toml").read_text(encoding="utf-8").replace(
        'name = "alni-1to1-300rpm-lab"', f'name = "{"a" * 995}"'), encoding="utf-8")
    shutil.copy(ROOT / "models" / "alni-1to1-300rpm-lab.moments.toml", tmp_path / "long.moments.toml")
    assert len(load_card(card).card.name) == 995
    out, written = tmp_path / "out" / "est.csv", tmp_path / "out" / "cal.toml"
    rc = main(["estimate", str(card), "--samples", str(ROOT / "examples" / "samples"), "--times", "0.5,1,2,4,8",
               "--estimator", "ukf", "--out", str(out), "--write-card", str(written), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "Traceback" not in err
    back = load_card(written)
    assert back.card.name == "a" * (TEXT_MAX_CHARS - 14) + "...-calibrated"
    assert back.card.sources[-1].endswith("from bmctl estimate on 5 samples to 8 h")
    assert out.exists() and out.with_suffix(".png").exists()
