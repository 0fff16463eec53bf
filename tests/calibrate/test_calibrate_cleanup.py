"""calibrate's cleanup of an earlier calibration's figures never removes one of the run's inputs."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bmctl.calibrate import outputs, run
from bmctl.calibrate.history import History, MeasuredSample
from bmctl.config import load_card
from bmctl.moments import forcard

from tests.conftest import card_path

LAB = card_path("alni-1to1-300rpm-lab")
PNG = b"\x89PNG\r\n\x1a\n a micrograph"


def _earlier_calibration(out: Path, *names: str) -> None:
    """What an earlier calibration left in ``out``: its calibration.json naming ``names``."""
    out.mkdir(exist_ok=True)
    (out / "calibration.json").write_text(json.dumps({"histories": [{"name": n} for n in names]}), encoding="utf-8")


@pytest.fixture
def cheap_run(monkeypatch):
    """run_calibration without the fit, the model runs, the figures' plotting and the identification:
    only its outputs' writing and the cleanup are real."""
    monkeypatch.setattr(run, "calibrate", lambda card, histories, names, **kw: SimpleNamespace(u=np.zeros(0),
                                                                                              values=[]))
    monkeypatch.setattr(run, "model_samples_at", lambda cal, card, histories, *a, **kw: [[] for _ in histories])
    monkeypatch.setattr(outputs, "sample_distances", lambda histories, kept: [])
    monkeypatch.setattr(outputs, "calibration_dict", lambda cal, histories, dist, meta:
                        {"histories": [{"name": h.name} for h in histories]})

    def plot(path, history, kept, title):
        Path(path).write_bytes(b"figure")
        return Path(path)

    monkeypatch.setattr(outputs, "plot_history", plot)
    monkeypatch.setattr(forcard, "identification_text", lambda *a, **kw: "# coefficients\n")

    def go(histories, out):
        return run.run_calibration(load_card(LAB), LAB, histories, [], out, moment_stage=False)

    return go


def _history(name: str, folder: Path, sample: Path) -> History:
    smp = MeasuredSample(1.0, np.ones(3), np.ones(3), str(sample))
    return History(name, str(folder / f"{name}.toml"), [(1.0, 300.0, 1.0)], [smp])


def test_a_sample_image_named_like_an_earlier_figure_is_not_removed(tmp_path, cheap_run):
    out = tmp_path / "out"
    _earlier_calibration(out, "old run", "micro", "new")
    old, micro = out / "histograms-old_run.png", out / "histograms-micro.png"
    old.write_bytes(b"old figure")
    micro.write_bytes(PNG)  # the user's micrograph, a sample of this run, bears an earlier figure's name
    res = cheap_run([_history("new", tmp_path, micro)], out)
    assert micro.read_bytes() == PNG
    assert not old.exists() and res.removed == [old]
    assert (out / "histograms-new.png").read_bytes() == b"figure"


def test_an_input_by_another_path_or_link_is_not_removed(tmp_path, cheap_run):
    out = tmp_path / "out"
    _earlier_calibration(out, "a", "b")
    a, b = out / "histograms-a.png", out / "histograms-b.png"
    a.write_bytes(PNG)
    b.write_bytes(PNG)
    link = tmp_path / "sample.png"
    link.symlink_to(b)  # the history names its sample by a link to a file in --out
    res = cheap_run([_history("h1", tmp_path, out / ".." / "out" / "histograms-a.png"), _history("h2", tmp_path, link)],
                    out)
    assert a.read_bytes() == PNG and b.read_bytes() == PNG and res.removed == []


def test_a_history_file_named_like_an_earlier_figure_is_not_removed(tmp_path, cheap_run):
    out = tmp_path / "out"
    _earlier_calibration(out, "x")
    hist = out / "histograms-x.png"
    hist.write_text("name = 'h'\n", encoding="utf-8")
    h = History("h", str(hist), [(1.0, 300.0, 1.0)], [MeasuredSample(1.0, np.ones(3), np.ones(3), "t.csv")])
    assert cheap_run([h], out).removed == []
    assert hist.is_file()


def test_figures_not_recorded_or_written_again_are_left(tmp_path, cheap_run):
    """Only figures the earlier calibration.json names are removed, and not one this run writes again."""
    out = tmp_path / "out"
    _earlier_calibration(out, "old", "again")
    for n in ("old", "again", "mine"):
        (out / f"histograms-{n}.png").write_bytes(b"x")
    res = cheap_run([_history("again", tmp_path, tmp_path / "s.png")], out)
    assert res.removed == [out / "histograms-old.png"] and not (out / "histograms-old.png").exists()
    assert (out / "histograms-mine.png").read_bytes() == b"x"
    assert (out / "histograms-again.png").read_bytes() == b"figure"


def test_stale_figures_spares_inputs(tmp_path):
    _earlier_calibration(tmp_path, "a", "b", "c")
    for n in "abc":
        (tmp_path / f"histograms-{n}.png").write_bytes(b"")
    got = run.stale_figures(tmp_path, [tmp_path / "histograms-a.png"], [tmp_path / "histograms-c.png"])
    assert got == [tmp_path / "histograms-b.png"]
