"""Unusual micrograph files and paths: what `bmctl measure` (and `bmctl compare`) read, what they
refuse in one line, and that their output set is written whole or not at all."""

from __future__ import annotations

import json
import logging
import os
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.measure.loading import load_image
from bmctl.measure.tables import ParticleTable, write_table
from .shapes import discs as _discs, cli as _cli

MODEL = Path(__file__).resolve().parents[2] / "models" / "alni-1to1-300rpm-lab.toml"
BAD_NAME = os.fsdecode(b"bad\xff\xfename")  # a folder name whose bytes are not UTF-8


def _one_error_line(err: str, name: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"bmctl: error: {name}"), err
    return lines[0]


# --- paths whose bytes are not UTF-8, and the output set ----------------------------------------

def test_measure_path_with_non_utf8_bytes_writes_the_whole_set(capsys, tmp_path):
    folder = tmp_path / BAD_NAME
    folder.mkdir()
    Image.fromarray(_discs()).save(folder / "ok.png")
    out = tmp_path / "out" / "t.csv"
    rc, stdout, err = _cli(capsys, ["measure", str(folder / "ok.png"), "--um-per-px", "0.5", "--out", str(out)])
    assert rc == 0, err
    stdout.encode("utf-8"), err.encode("utf-8")  # printable on a strict UTF-8 terminal (no lone surrogates)
    assert "bad\\xff\\xfename" in stdout
    table = out.read_text(encoding="utf-8")  # the table is UTF-8: the bytes are written as escapes
    assert "bad\\xff\\xfename/ok.png" in table
    doc = json.loads((out.parent / "measure.json").read_text(encoding="utf-8"))
    assert doc["inputs"][0]["image"] == str(folder / "ok.png")  # JSON keeps the exact path (\udcff escapes)
    assert sorted(p.name for p in out.parent.iterdir()) == ["measure.json", "ok.overlay.png", "t.csv"]


def test_measure_late_write_failure_leaves_none_of_the_set(capsys, tmp_path, monkeypatch):
    import bmctl.measure.tables as tables

    def full_disk(path, *a, **k):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(tables, "write_table", full_disk)
    Image.fromarray(_discs()).save(tmp_path / "ok.png")
    out = tmp_path / "out" / "t.csv"
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "ok.png"), "--um-per-px", "0.5", "--out", str(out)])
    assert rc == 2
    _one_error_line(err, str(out))
    assert not out.parent.exists()  # no overlay, no measure.json, no temporary file: not even the folder it made


def _sample_table(path: Path) -> None:
    rng = np.random.default_rng(0)
    write_table(path, ParticleTable.from_size_aspect(rng.lognormal(np.log(40.0), 0.3, 50), rng.uniform(0.0, 0.2, 50)))


def test_compare_path_with_non_utf8_bytes(capsys, tmp_path):
    folder = tmp_path / BAD_NAME
    folder.mkdir()
    _sample_table(folder / "t.csv")
    out = folder / "cmp"
    rc, stdout, err = _cli(capsys, ["compare", str(folder / "t.csv"), "--model", str(MODEL), "--at-h", "0.5",
                                    "--particles", "100", "--out", str(out)])
    assert rc == 0, err
    stdout.encode("utf-8")
    assert "bad\\xff\\xfename" in stdout
    assert (out / "compare.png").is_file()
    assert json.loads((out / "compare.json").read_text(encoding="utf-8"))["sample"] == str(folder / "t.csv")


def test_compare_late_write_failure_leaves_neither_file(capsys, tmp_path, monkeypatch):
    import bmctl.io

    def full_disk(path, text):
        raise OSError(28, "No space left on device", str(path))

    _sample_table(tmp_path / "t.csv")
    monkeypatch.setattr(bmctl.io, "write_text", full_disk)
    out = tmp_path / "cmp"
    rc, _, err = _cli(capsys, ["compare", str(tmp_path / "t.csv"), "--model", str(MODEL), "--at-h", "0.5",
                               "--particles", "100", "--out", str(out)])
    assert rc == 2
    _one_error_line(err, str(out / "compare.json"))
    assert not out.exists() or list(out.iterdir()) == []


# --- files refused in one line -------------------------------------------------------------------

def _complex_tif(path: Path) -> None:
    import tifffile

    tifffile.imwrite(path, (np.random.default_rng(0).random((64, 64)) + 1j).astype(np.complex64))


def _stack_tif(path: Path) -> None:
    import tifffile

    tifffile.imwrite(path, np.stack([_discs()] * 3), photometric="minisblack")


def _two_frame_gif(path: Path) -> None:
    frames = [Image.fromarray(_discs()), Image.fromarray(255 - _discs())]
    frames[0].save(path, save_all=True, append_images=frames[1:])


def _transparent_png(path: Path) -> None:
    rgba = np.dstack([_discs()] * 3 + [np.full((128, 128), 255, np.uint8)])
    rgba[:20, :20, 3] = 0
    Image.fromarray(rgba).save(path)


def _no_page_tif(path: Path) -> None:
    path.write_bytes(b"II*\x00\x08\x00\x00\x00")  # the first page's offset points at the header itself


REFUSED = {
    "complex.tif": (_complex_tif, "pixel type complex64"),
    "stack.tif": (_stack_tif, "holds 3 images"),
    "anim.gif": (_two_frame_gif, "holds 2 images"),
    "alpha.png": (_transparent_png, "transparent pixels (alpha)"),
    "nopage.tif": (_no_page_tif, "holds no image"),
}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_load_image_refuses(tmp_path, name):
    make, why = REFUSED[name]
    make(tmp_path / name)
    with pytest.raises(InputError, match=re.escape(why)):
        load_image(tmp_path / name)


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_cli_refuses_in_one_line_and_writes_nothing(capsys, caplog, tmp_path, name):
    make, why = REFUSED[name]
    make(tmp_path / name)
    out = tmp_path / "out" / "t.csv"
    caplog.set_level(logging.DEBUG)
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / name), "--um-per-px", "0.5", "--out", str(out)])
    assert rc == 2
    assert why in _one_error_line(err, str(tmp_path / name))
    assert not [r for r in caplog.records if r.name.startswith("tifffile")]  # tifffile's own log lines silenced
    assert not out.parent.exists()


# --- files read as one gray image ----------------------------------------------------------------

@pytest.mark.parametrize("name", ["cmyk.jpg", "cmyk.tif"])
def test_cmyk_is_read_as_its_gray(tmp_path, name):
    Image.fromarray(_discs()).convert("CMYK").save(tmp_path / name, **({"quality": 95} if name.endswith(".jpg") else {}))
    img = load_image(tmp_path / name)
    assert img.shape == (128, 128)
    assert np.corrcoef(img.ravel(), _discs().ravel().astype(float))[0, 1] > 0.95
    assert img[64, 64] - img[0, 0] > 0.5  # a bright disc on a dark background, as drawn


@pytest.mark.parametrize("mode", ["P", "L"])
def test_single_frame_gif_is_one_gray_image(tmp_path, mode):
    Image.fromarray(_discs()).convert(mode).save(tmp_path / "one.gif")
    img = load_image(tmp_path / "one.gif")
    assert img.shape == (128, 128)
    assert np.allclose(img, _discs() / 255.0, atol=0.02)


@pytest.mark.parametrize("mode", ["LA", "RGBA"])
def test_opaque_alpha_is_dropped(tmp_path, mode):
    Image.fromarray(_discs()).convert(mode).save(tmp_path / "a.png")
    assert np.allclose(load_image(tmp_path / "a.png"), _discs() / 255.0, atol=0.01)


def test_planar_rgb_tiff_and_reduced_page_are_one_image(tmp_path):
    import tifffile

    rgb = np.stack([_discs()] * 3)
    tifffile.imwrite(tmp_path / "planar.tif", rgb, photometric="rgb", planarconfig="separate")
    assert np.allclose(load_image(tmp_path / "planar.tif"), _discs() / 255.0)
    tifffile.imwrite(tmp_path / "thumb.tif", _discs())
    tifffile.imwrite(tmp_path / "thumb.tif", _discs()[::4, ::4], append=True, subfiletype=1)  # a reduced-resolution preview
    assert load_image(tmp_path / "thumb.tif").shape == (128, 128)


def test_tifffile_log_lines_are_silenced(capsys, caplog, tmp_path):
    _no_page_tif(tmp_path / "h.tif")
    caplog.set_level(logging.DEBUG)
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "h.tif"), "--um-per-px", "0.5"])
    assert rc == 2
    _one_error_line(err, str(tmp_path / "h.tif"))
    assert not [r for r in caplog.records if r.name.startswith("tifffile")]  # tifffile would print them to stderr


def test_a_gray_frame_stored_with_a_leading_axis_is_one_image(tmp_path):
    """A one-page TIFF written as 1 x H x W (and some gray GIFs, read that way) was refused as
    "not a 2-D gray or colour image (shape (1, H, W))"."""
    import tifffile

    gray = (_discs() * (255 // max(int(_discs().max()), 1))).astype(np.uint8)
    tifffile.imwrite(tmp_path / "page.tif", gray[None])
    Image.fromarray(gray, mode="L").save(tmp_path / "gray.gif")
    for name in ("page.tif", "gray.gif"):
        assert load_image(tmp_path / name).shape == gray.shape, name


def test_one_image_given_twice_is_not_measured_twice(tmp_path, capsys):
    Image.fromarray(_discs()).convert("L").save(tmp_path / "m.png")
    rc = main(["measure", str(tmp_path / "m.png"), str(tmp_path / "m.png"), "--um-per-px", "0.5",
               "--out", str(tmp_path / "t.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "given twice" in err[0], err
    assert not (tmp_path / "t.csv").exists()


def test_tiff_whose_last_page_links_back_is_read_not_looped_over(tmp_path):
    """A TIFF whose page chain points back to its first page: counting its pixels for the work
    budget iterated tifffile's pages forever (``bmctl measure`` hung before reading it)."""
    import struct
    import threading

    import tifffile

    from bmctl.measure.loading import image_header

    path = tmp_path / "loop.tif"
    tifffile.imwrite(path, _discs())
    data = bytearray(path.read_bytes())
    first = struct.unpack("<I", data[4:8])[0]
    n = struct.unpack("<H", data[first:first + 2])[0]
    data[first + 2 + 12 * n:first + 6 + 12 * n] = struct.pack("<I", first)  # next page: the first again
    path.write_bytes(bytes(data))
    got = []
    worker = threading.Thread(target=lambda: got.append(image_header(str(path))), daemon=True)
    worker.start()
    worker.join(20)
    assert got and got[0].pixels == 128 * 128 and got[0].images == 1, got


def test_file_under_a_misleading_extension_is_read_as_what_it_holds(tmp_path, capsys):
    """The reader was chosen by the file's name: a PNG saved as ``.tif`` was refused ("cannot read
    image (TiffFileError)") and a calibrated TIFF renamed ``.png`` lost its pixel size."""
    import tifffile

    Image.fromarray(_discs()).save(tmp_path / "png_inside.tif", format="PNG")
    assert np.allclose(load_image(tmp_path / "png_inside.tif"), _discs() / 255.0)
    tifffile.imwrite(tmp_path / "tif_inside.png", _discs(), imagej=True, resolution=(2, 2), metadata={"unit": "micron"})
    assert np.allclose(load_image(tmp_path / "tif_inside.png"), _discs() / 255.0)
    rc, out, err = _cli(capsys, ["measure", str(tmp_path / "png_inside.tif"), "--um-per-px", "0.5"])
    assert rc == 0 and "particles; 0.5 µm/px from user" in out, err
    rc, out, err = _cli(capsys, ["measure", str(tmp_path / "tif_inside.png")])
    assert rc == 0 and "0.5 µm/px from metadata" in out, err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_cli_refuses_a_named_pipe_without_waiting_for_a_writer(tmp_path, capsys):
    """The work-budget check opened every image's header before the input check, so a FIFO
    given as IMAGE blocked ``bmctl measure`` forever instead of being refused."""
    import threading

    os.mkfifo(tmp_path / "pipe.png")
    got = []
    worker = threading.Thread(target=lambda: got.append(main(["measure", str(tmp_path / "pipe.png"), "--um-per-px", "0.5"])),
                              daemon=True)
    worker.start()
    worker.join(20)
    in_time = list(got)
    if not got:  # unblock the reader so the thread can end
        with open(tmp_path / "pipe.png", "wb"):
            pass
        worker.join(5)
    assert in_time == [2], "bmctl measure waited on the pipe"
    assert "not a regular file" in _one_error_line(capsys.readouterr().err, str(tmp_path / "pipe.png"))


def test_large_images_print_progress_per_input_and_small_ones_do_not(tmp_path, capsys):
    """Work estimated over 5 s (here 0.6 Mpx of tiled discs) prints a line per input on stderr before
    it is measured, and one when all are measured; --no-progress and a small image print none."""
    big = tmp_path / "big.png"
    Image.fromarray(np.tile(_discs(), (6, 6))).save(big)  # 768 x 768 px
    small = tmp_path / "small.png"
    Image.fromarray(_discs()).save(small)
    rc, _, err = _cli(capsys, ["measure", str(small), str(big), "--um-per-px", "0.5"])
    lines = [ln for ln in err.splitlines() if "] measure: " in ln]
    assert rc == 0 and len(lines) == 3, err
    assert lines[1].endswith(f"measure: input 2 of 2: {big} (0.6 Mpx)") and lines[-1].endswith("measure: measured")
    rc, _, err = _cli(capsys, ["measure", str(small), str(big), "--um-per-px", "0.5", "--no-progress"])
    assert rc == 0 and "] measure: " not in err
    rc, _, err = _cli(capsys, ["measure", str(small), "--um-per-px", "0.5"])
    assert rc == 0 and "] measure: " not in err


def test_a_truncated_png_after_a_good_image_is_refused_before_anything_is_measured(tmp_path, capsys, monkeypatch):
    """The header of a PNG cut in half reads fine; its chunks do not: it is named in one line before
    the good image before it is measured (it was refused only after that image's segmentation)."""
    import bmctl.measure.micrograph as micrograph

    good, cut = tmp_path / "good.png", tmp_path / "cut.png"
    Image.fromarray(np.tile(_discs(), (2, 2))).save(good)
    data = good.read_bytes()
    cut.write_bytes(data[: len(data) // 2])

    def measured(*a, **k):
        raise AssertionError("an image was measured")

    monkeypatch.setattr(micrograph, "measure_micrograph", measured)
    rc, out, err = _cli(capsys, ["measure", str(good), str(cut), "--um-per-px", "0.5"])
    assert rc == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"bmctl: error: {cut}: cannot read image (a damaged or truncated PNG")
