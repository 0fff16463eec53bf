"""`bmctl measure --out`: the output set (table, measure.json, overlays) never replaces an input or
one of its own files, is valid JSON when an image has no particles, and every printed line names
a file on one line."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import bmctl.measure.micrograph as micrograph
from bmctl.cli import main
from bmctl.errors import one_line
from bmctl.measure.micrograph import check_verdicts, table_reports
from bmctl.measure.names import path_text
from .shapes import discs as _discs


def _noise(size: int = 20) -> np.ndarray:
    """A small image of pixel noise: no particle is found in it."""
    return (np.random.default_rng(0).random((size, size)) * 255).astype(np.uint8)


def _cli(capsys, argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _refused(capsys, argv, expected: str) -> None:
    rc, out, err = _cli(capsys, argv)
    lines = err.strip().splitlines()
    assert rc == 2 and out == "", (rc, out, err)
    assert len(lines) == 1 and lines[0] == f"bmctl: error: {expected}", err


@pytest.fixture
def no_measuring(monkeypatch):
    """Fail the test if an image is measured: a refusal comes before any work."""
    def measured(*a, **k):
        raise AssertionError("an image was measured before the output names were checked")
    monkeypatch.setattr(micrograph, "measure_micrograph", measured)


def _files(folder: Path) -> dict:
    return {p.name: (p.read_bytes() if p.is_file() else None) for p in folder.iterdir()}


# --- --out naming an input ------------------------------------------------------------------------

@pytest.mark.parametrize("how", ["same", "dot", "symlink", "symlink-input", "hardlink"])
def test_out_naming_an_input_image_is_refused_and_the_image_kept(capsys, tmp_path, monkeypatch, no_measuring, how):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    image, out, also = "grey.png", "grey.png", ""
    if how == "dot":
        out = "./grey.png"
    elif how == "symlink":
        os.symlink("grey.png", "link.png")
        out, also = "link.png", " (grey.png)"
    elif how == "symlink-input":
        os.symlink("grey.png", "link.png")
        image, also = "link.png", " (link.png)"
    elif how == "hardlink":
        os.link("grey.png", "hard.png")
        out, also = "hard.png", " (grey.png)"
    before = _files(tmp_path)
    _refused(capsys, ["measure", image, "--um-per-px", "0.5", "--out", out], f"--out: {out} is one of the inputs{also}")
    assert _files(tmp_path) == before  # the image is unchanged; no overlay, no measure.json


def test_out_naming_an_input_table_is_refused_and_the_table_kept(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    rc, _, err = _cli(capsys, ["measure", "grey.png", "--um-per-px", "0.5", "--out", "t/t.csv", "--no-overlay"])
    assert rc == 0, err
    os.replace("t/t.csv", "t.csv")
    before = _files(tmp_path)
    _refused(capsys, ["measure", "t.csv", "grey.png", "--um-per-px", "0.5", "--out", "t.csv"],
             "--out: t.csv is one of the inputs")
    assert _files(tmp_path) == before


# --- outputs that are each other, or an input ----------------------------------------------------

def test_out_named_measure_json_is_refused(capsys, tmp_path, monkeypatch, no_measuring):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    _refused(capsys, ["measure", "grey.png", "--um-per-px", "0.5", "--out", "measure.json"],
             "--out: measure.json would be overwritten by the measure.json written beside it; choose another name")
    assert sorted(os.listdir(tmp_path)) == ["grey.png"]


def test_out_named_as_an_overlay_is_refused_unless_no_overlay(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    _refused(capsys, ["measure", "grey.png", "--um-per-px", "0.5", "--out", "grey.overlay.png"],
             "--out: grey.overlay.png would be overwritten by the overlay of grey.png; "
             "choose another name or pass --no-overlay")
    assert sorted(os.listdir(tmp_path)) == ["grey.png"]
    rc, _, err = _cli(capsys, ["measure", "grey.png", "--um-per-px", "0.5", "--out", "grey.overlay.png", "--no-overlay"])
    assert rc == 0, err  # no overlay written: the name is free
    assert sorted(os.listdir(tmp_path)) == ["grey.overlay.png", "grey.png", "measure.json"]


def test_an_overlay_that_would_replace_an_input_image_is_refused(capsys, tmp_path, monkeypatch, no_measuring):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    Image.fromarray(_discs(96)).save("grey.overlay.png")
    before = _files(tmp_path)
    _refused(capsys, ["measure", "grey.png", "grey.overlay.png", "--um-per-px", "0.5", "--out", "p.csv"],
             "--out: the overlay of grey.png (grey.overlay.png) would overwrite the input grey.overlay.png; "
             "choose another folder for --out or pass --no-overlay")
    assert _files(tmp_path) == before


def test_two_overlays_that_are_one_file_are_refused(capsys, tmp_path, no_measuring):
    for d, name in (("d1", "a.png"), ("d2", "b.png")):
        (tmp_path / d).mkdir()
        Image.fromarray(_discs()).save(tmp_path / d / name)
    (tmp_path / "q").mkdir()
    os.symlink("b.overlay.png", tmp_path / "q" / "a.overlay.png")  # a.png's overlay would be written into b.png's
    a, b, q = tmp_path / "d1" / "a.png", tmp_path / "d2" / "b.png", tmp_path / "q"
    _refused(capsys, ["measure", a, b, "--um-per-px", "0.5", "--out", q / "p.csv"],
             f"--out: the overlay of {a} ({q / 'a.overlay.png'}) and the overlay of {b} ({q / 'b.overlay.png'}) "
             "are the same file; choose another folder for --out or pass --no-overlay")
    assert sorted(os.listdir(q)) == ["a.overlay.png"]


def test_out_empty_is_refused(capsys, tmp_path, monkeypatch, no_measuring):
    monkeypatch.chdir(tmp_path)
    Image.fromarray(_discs()).save("grey.png")
    _refused(capsys, ["measure", "grey.png", "--um-per-px", "0.5", "--out", ""], "--out: empty path")
    assert sorted(os.listdir(tmp_path)) == ["grey.png"]


def test_distinct_outputs_still_write_the_whole_set(capsys, tmp_path):
    """Two images of one stem in other folders get numbered overlays: no false refusal."""
    for d in ("d1", "d2"):
        (tmp_path / d).mkdir()
        Image.fromarray(_discs()).save(tmp_path / d / "m.png")
    out = tmp_path / "o" / "p.csv"
    rc, _, err = _cli(capsys, ["measure", tmp_path / "d1" / "m.png", tmp_path / "d2" / "m.png", "--um-per-px", "0.5",
                               "--out", out])
    assert rc == 0, err
    assert sorted(os.listdir(out.parent)) == ["m-2.overlay.png", "m.overlay.png", "measure.json", "p.csv"]


# --- measure.json with an image of no particles ----------------------------------------------------

def _strict_json(text: str):
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_measure_json_is_valid_json_when_an_image_has_no_particles(capsys, tmp_path):
    Image.fromarray(_discs()).save(tmp_path / "discs.png")
    Image.fromarray(_noise()).save(tmp_path / "noise.png")
    out = tmp_path / "o" / "p.csv"
    rc, _, err = _cli(capsys, ["measure", tmp_path / "discs.png", tmp_path / "noise.png", "--um-per-px", "0.5",
                               "--out", out])
    assert rc == 0, err
    text = (out.parent / "measure.json").read_text(encoding="utf-8")
    doc = _strict_json(text)  # no bare NaN
    empty = doc["inputs"][1]
    assert empty["count"] == 0 and empty["s_median_um"] is None and empty["r_median"] is None
    assert doc["inputs"][0]["count"] == 9 and doc["inputs"][0]["s_median_um"] > 0
    # the readers of measure.json (bmctl estimate, campaign sample) still read its verdicts
    reports = table_reports(out)
    assert [r["verdict"]["value"] for r in reports] == [doc["inputs"][0]["verdict"]["value"], "unusable"]
    with pytest.raises(Exception, match="noise.png: verdict unusable"):
        check_verdicts(reports)
    assert any("noise.png: verdict unusable" in w for w in check_verdicts(reports, accept_unusable=True))


def test_report_of_an_image_without_particles_has_no_nan():
    res = micrograph.measure_micrograph(_noise(), um_per_px=0.5)
    rep = res.report()
    assert rep["count"] == 0 and rep["s_median_um"] is None and rep["r_median"] is None
    json.dumps(rep, allow_nan=False)


# --- control characters in names ------------------------------------------------------------------

def test_path_text_escapes_control_characters_as_error_messages_do():
    name = "a\nb\rc\td\x1be\x7ff\x85g\u2028h.png"
    assert path_text(name) == one_line(name)
    assert "\n" not in path_text(name) and "\x1b" not in path_text(name)
    assert path_text("plain/µm.png") == "plain/µm.png"


@pytest.mark.parametrize("name", ["nl\nname.png", "cr\rname.png", "esc\x1b[2Jname.png"])
def test_a_name_with_control_characters_is_printed_on_one_line(capsys, tmp_path, name):
    Image.fromarray(_discs()).save(tmp_path / name)
    out = tmp_path / "o" / "p.csv"
    rc, stdout, err = _cli(capsys, ["measure", tmp_path / name, "--um-per-px", "0.5", "--out", out])
    assert rc == 0, err
    shown = f"{tmp_path}/{one_line(name)}"  # escaped as in an error message
    for text in (stdout, err):
        assert "\r" not in text and "\x1b" not in text
    lines = stdout.splitlines()
    assert len(lines) == 2 and lines[0].startswith(f"{shown}: 9 particles;") and lines[1].startswith("measure: 9 particles")
    for line in err.splitlines():  # the polarity and verdict line, and any warning, each on one line naming the file
        assert line.startswith((f"bmctl: {shown}: ", f"bmctl: warning: {shown}: ")), err
    rows = (out).read_text(encoding="utf-8").splitlines()
    assert len(rows) == 1 + 9 and all(f",{shown}," in r for r in rows[1:])  # one table row per particle


def test_one_particle_is_counted_in_the_singular(tmp_path, capsys):
    """A crop holding one particle: "1 particle", not "1 particles"."""
    from .shapes import cli

    img = np.full((64, 64), 30, np.uint8)
    yy, xx = np.mgrid[:64, :64]
    img[(yy - 32) ** 2 + (xx - 32) ** 2 <= 49] = 220
    Image.fromarray(img).save(tmp_path / "one.png")
    rc, out, err = cli(capsys, ["measure", str(tmp_path / "one.png"), "--um-per-px", "1", "--out",
                                str(tmp_path / "o" / "p.csv")])
    assert rc == 0, err
    assert "1 particle," in out and "1 particles" not in out + err, out + err
