"""Micrograph samples in histories, a history file given twice, and the calibration's output set."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bmctl.calibrate.history import load_history
from bmctl.cli import main
from bmctl.config import load_card
from bmctl.errors import InputError

from tests.conftest import card_path

LAB = card_path("alni-1to1-300rpm-lab")

HISTORY = """name = "h"
[[segment]]
hours = 3
rpm = 300
[[sample]]
t_h = 1.0
image = "{image}"
um_per_px = 0.5
"""


def _save(path: Path, img: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(img.astype(np.uint8)).save(path)


def _history(tmp_path: Path, image: str) -> Path:
    p = tmp_path / "hist.toml"
    p.write_text(HISTORY.format(image=image), encoding="utf-8")
    return p


def test_a_noise_image_that_measures_as_unusable_is_refused_naming_file_and_field(tmp_path):
    """Blurred, thresholded noise: hundreds of 'particles', verdict unusable in bmctl measure and
    estimate; calibrate fitted them as a sample."""
    from scipy import ndimage as ndi

    x = ndi.gaussian_filter(np.random.default_rng(0).normal(size=(300, 300)), 1.5)
    x = (x - x.min()) / np.ptp(x)
    _save(tmp_path / "noise.png", np.where(x > 0.6, x, 0.2) * 255)
    p = _history(tmp_path, "noise.png")
    with pytest.raises(InputError) as err:
        load_history(p)
    msg = str(err.value)
    assert "\n" not in msg and "hist.toml: sample[0].image" in msg and "unusable" in msg
    h = load_history(p, accept_unusable=True)  # kept on request, with a warning naming it
    assert h.samples[0].s_um.size >= 10 and "unusable" in h.warnings[0] and "sample[0].image" in h.warnings[0]


def test_an_unmeasurable_image_names_the_history_and_the_field(tmp_path):
    _save(tmp_path / "flat.png", np.full((64, 64), 128))
    with pytest.raises(InputError, match=r"hist.toml: sample\[0\]\.image: .*flat.png"):
        load_history(_history(tmp_path, "flat.png"))


def test_a_history_file_given_twice_is_named_as_such(tmp_path, capsys, monkeypatch):
    p = _history(tmp_path, "x.png")
    monkeypatch.chdir(tmp_path)
    rc = main(["calibrate", str(LAB), "hist.toml", "./hist.toml", "--workers", "0", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "given twice" in err and p.name in err


def test_an_interrupt_while_writing_the_figures_leaves_no_output(tmp_path, monkeypatch):
    """Card, coefficients, calibration.json and figures are one set: Ctrl-C in the last figure
    leaves none of them (it left the card and its coefficients without calibration.json)."""
    from bmctl.calibrate import outputs, run
    from bmctl.calibrate.history import History, MeasuredSample
    from bmctl.moments import forcard

    card = load_card(LAB)
    fake = SimpleNamespace(values=np.array([card.stochastic.gamma_per_um2]))
    monkeypatch.setattr(run, "calibrate", lambda *a, **k: fake)
    monkeypatch.setattr(run, "model_samples_at", lambda *a, **k: [[]])
    monkeypatch.setattr(outputs, "sample_distances", lambda *a, **k: [])
    monkeypatch.setattr(outputs, "calibration_dict", lambda *a, **k: {})
    monkeypatch.setattr(forcard, "identification_text", lambda *a, **k: "# coefficients\n")

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "plot_history", interrupted)
    h = History("h", "h.toml", [(1.0, 300.0, 1.0)], [MeasuredSample(1.0, np.ones(10), np.zeros(10), "t")])
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run.run_calibration(card, LAB, [h], ["gamma"], out, moment_stage=False)
    assert not out.exists() or list(out.iterdir()) == []
