"""Reading micrographs: a TIFF's Orientation tag, one file given twice to `bmctl measure`, a
transparent colour in a PNG of 16-bit colour or of 1-, 2- or 4-bit gray, and where the measurement
benchmarks look for their data."""

from __future__ import annotations

import json
import os
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from bmctl.errors import InputError
from bmctl.measure.loading import TRANSPARENT, load_image
from tests.conftest import load_benchmark
from .shapes import discs as _discs, cli as _cli

ROOT = Path(__file__).resolve().parents[2]


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    return lines[0]


# --- a TIFF's Orientation tag ---------------------------------------------------------------------

def _shown(a: np.ndarray, orientation: int) -> np.ndarray:
    """``a`` (H, W) as a viewer shows it under ``orientation`` (Pillow's ``exif_transpose``)."""
    im = Image.fromarray(a)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.info["exif"] = exif.tobytes()
    return np.asarray(ImageOps.exif_transpose(im))


def _wide() -> np.ndarray:
    """A gray uint8 image, 128 x 192 px: twelve discs."""
    return np.hstack([_discs(), _discs()[:, :64]])


@pytest.mark.parametrize("orientation", range(1, 9))
def test_a_tiff_is_read_as_its_orientation_tag_shows_it(tmp_path, orientation):
    """tifffile hands over the pixels as stored: a TIFF whose Orientation tag says they are shown
    turned or flipped was measured as stored (only Pillow's EXIF path turned an image)."""
    import tifffile

    a = np.random.default_rng(orientation).integers(0, 256, (24, 40)).astype(np.uint8)
    tifffile.imwrite(tmp_path / "turned.tif", a, extratags=[(274, "H", 1, orientation, True)])
    tifffile.imwrite(tmp_path / "shown.tif", _shown(a, orientation))
    tifffile.imwrite(tmp_path / "big.tif", a, byteorder=">", bigtiff=True, extratags=[(274, "H", 1, orientation, True)])
    shown = load_image(tmp_path / "shown.tif")
    assert np.array_equal(load_image(tmp_path / "turned.tif"), shown)
    assert np.array_equal(load_image(tmp_path / "big.tif"), shown)
    if orientation == 1:  # as stored: the same as a TIFF without the tag
        tifffile.imwrite(tmp_path / "plain.tif", a)
        assert np.array_equal(load_image(tmp_path / "plain.tif"), load_image(tmp_path / "turned.tif"))


@pytest.mark.parametrize("orientation", (2, 3, 6, 8))
def test_a_turned_cmyk_tiff_is_turned_once(tmp_path, orientation):
    """A CMYK TIFF is converted by Pillow, which turns a TIFF itself (and garbles one turned a
    quarter): it is turned once, as a gray TIFF is."""
    import tifffile

    inks = np.random.default_rng(orientation).integers(0, 256, (24, 40, 4)).astype(np.uint8)
    tifffile.imwrite(tmp_path / "turned.tif", inks, photometric="separated", extratags=[(274, "H", 1, orientation, True)])
    shown = np.stack([_shown(inks[..., k], orientation) for k in range(4)], axis=-1)
    tifffile.imwrite(tmp_path / "shown.tif", shown, photometric="separated")
    assert np.array_equal(load_image(tmp_path / "turned.tif"), load_image(tmp_path / "shown.tif"))


def test_a_turned_tiff_is_measured_and_cropped_as_displayed(tmp_path, capsys):
    import tifffile

    g = _wide()
    tifffile.imwrite(tmp_path / "turned.tif", np.ascontiguousarray(np.rot90(g, 1)),  # stored a quarter turn anticlockwise,
                     extratags=[(274, "H", 1, 6, True)])  # shown turned back
    out = tmp_path / "o" / "t.csv"
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "turned.tif"), "--um-per-px", "0.5", "--crop", "0:120,0:190",
                               "--no-overlay", "--out", str(out)])
    assert rc == 0, err  # 190 columns: the displayed image has 192, the stored one 128
    report = json.loads((out.parent / "measure.json").read_text(encoding="utf-8"))["inputs"][0]
    assert report["shape_px"] == list(g.shape)


# --- one file given twice ---------------------------------------------------------------------------

@pytest.mark.parametrize("second", ["same path", "dot path", "symlink", "hard link"])
def test_one_file_given_twice_is_refused_naming_both_before_any_is_read(tmp_path, capsys, monkeypatch, second):
    """A hard link to an input was measured as a second image (its particles counted twice); the
    same path or a symbolic link was refused naming only one of the two arguments."""
    import bmctl.measure.loading as loading

    Image.fromarray(_discs()).save(tmp_path / "a.png")
    first = str(tmp_path / "a.png")
    other = {"same path": first, "dot path": os.path.join(str(tmp_path), ".", "a.png"), "symlink": str(tmp_path / "sym.png"),
             "hard link": str(tmp_path / "hard.png")}[second]
    if second == "symlink":
        os.symlink("a.png", other)
    elif second == "hard link":
        os.link(first, other)

    def no_reading(*a, **k):
        raise AssertionError("an input was read")

    monkeypatch.setattr(loading, "image_header", no_reading)
    monkeypatch.setattr(loading, "load_image", no_reading)
    out = tmp_path / "o" / "t.csv"
    rc, stdout, err = _cli(capsys, ["measure", first, other, "--um-per-px", "0.5", "--out", str(out)])
    line = _one_error_line(err)
    assert rc == 2 and not stdout
    assert line.startswith(f"bmctl: error: {other}: given twice") and "give each image or table once" in line, line
    if other != first:
        assert f"(the same file as {first})" in line, line
    assert not out.parent.exists()


def test_two_files_of_the_same_pixels_are_both_measured(tmp_path, capsys):
    Image.fromarray(_discs()).save(tmp_path / "a.png")
    Image.fromarray(_discs()).save(tmp_path / "b.png")  # the same pixels in another file: measured twice, as asked
    rc, stdout, err = _cli(capsys, ["measure", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--um-per-px", "0.5"])
    assert rc == 0, err
    assert "measure: 18 particles" in stdout


# --- a transparent colour in PNGs of other sample depths ----------------------------------------------

def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _png(path, rows: list[bytes], width: int, height: int, depth: int, colour_type: int, key: bytes | None) -> None:
    data = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, 0))
    if key is not None:
        data += _chunk(b"tRNS", key)
    Path(path).write_bytes(data + _chunk(b"IDAT", zlib.compress(b"".join(rows))) + _chunk(b"IEND", b""))


def _rgb16_png(path, px: np.ndarray, key=None) -> None:
    """A 16-bit RGB PNG of ``px`` (H, W, 3) uint16, its transparent colour ``key``; rows filtered
    in turn with none, Sub (the pixel before) and Up (the row above)."""
    h, w, _ = px.shape
    raw = [px[y].astype(">u2").tobytes() for y in range(h)]
    rows = []
    for y, row in enumerate(raw):
        b = np.frombuffer(row, np.uint8).astype(np.int64)
        if y % 3 == 1:  # Sub: minus the byte 6 before (one pixel)
            rows.append(b"\x01" + ((b - np.concatenate([np.zeros(6, np.int64), b[:-6]])) % 256).astype(np.uint8).tobytes())
        elif y % 3 == 2:  # Up: minus the byte above
            rows.append(b"\x02" + ((b - np.frombuffer(raw[y - 1], np.uint8)) % 256).astype(np.uint8).tobytes())
        else:
            rows.append(b"\x00" + row)
    _png(path, rows, w, h, 16, 2, None if key is None else struct.pack(">HHH", *key))


def _gray_png(path, px: np.ndarray, depth: int, key=None) -> None:
    """A gray PNG of ``px`` (H, W) samples of ``depth`` bits (1, 2 or 4), its transparent gray ``key``."""
    rows = []
    for row in px:
        bits = np.unpackbits(row.astype(np.uint8)[:, None], axis=1)[:, 8 - depth:].ravel()
        rows.append(b"\x00" + np.packbits(bits).tobytes())
    _png(path, rows, px.shape[1], px.shape[0], depth, 0, None if key is None else struct.pack(">H", key))


def _rgb16() -> np.ndarray:
    """A 16-bit RGB image of discs (bright ones 50,000-ish, a dark background) with noise in the low bytes."""
    rng = np.random.default_rng(0)
    g = _discs(64).astype(np.uint16) * 256
    return np.stack([g, g // 2, g // 3], axis=-1) + rng.integers(0, 200, (64, 64, 3)).astype(np.uint16)


def test_a_16_bit_rgb_png_with_pixels_of_its_transparent_colour_is_refused(tmp_path):
    """The transparent colour of a 16-bit PNG is given in 16 bits; it was compared with the 8-bit
    pixels Pillow decodes (their high bytes), so such pixels were measured as opaque."""
    px = _rgb16()
    key = tuple(int(v) for v in px[10, 20])
    _rgb16_png(tmp_path / "keyed.png", px, key)
    with pytest.raises(InputError, match=re.escape(TRANSPARENT)):
        load_image(tmp_path / "keyed.png")


def test_a_16_bit_rgb_png_without_pixels_of_its_transparent_colour_is_read_as_before(tmp_path):
    """Pixels whose high bytes are those of the transparent colour but not all 16 bits are opaque."""
    px = _rgb16()
    _rgb16_png(tmp_path / "plain.png", px)
    plain = load_image(tmp_path / "plain.png")
    key = tuple(int(v) for v in px[10, 20])
    near = (key[0], key[1], key[2] ^ 1)  # the same high bytes, another low byte: no pixel has it
    assert not np.any(np.all(px == near, axis=-1)) and np.any(np.all(px >> 8 == np.asarray(near) >> 8, axis=-1))
    _rgb16_png(tmp_path / "near.png", px, near)
    _rgb16_png(tmp_path / "far.png", px, (1, 2, 3))
    for name in ("near.png", "far.png"):
        assert np.array_equal(load_image(tmp_path / name), plain), name


@pytest.mark.parametrize("depth", (1, 2, 4))
def test_a_low_depth_gray_png_with_pixels_of_its_transparent_gray_is_refused(tmp_path, depth):
    """Pillow decodes 1-, 2- and 4-bit gray samples to 0-255 (bool for 1 bit) but gives the transparent
    gray as a sample: only a transparent black was found."""
    top = 2 ** depth - 1
    px = np.where(_discs(32) > 100, top, 0).astype(np.uint8)
    px[0, :3] = 1  # a pixel of the sample 1 too
    for key in (top, 1):
        _gray_png(tmp_path / "keyed.png", px, depth, key)
        with pytest.raises(InputError, match="transparent pixels"):
            load_image(tmp_path / "keyed.png")
    _gray_png(tmp_path / "plain.png", px, depth)
    plain = load_image(tmp_path / "plain.png")
    if depth > 1:  # a gray no pixel has
        _gray_png(tmp_path / "unused.png", px, depth, 2)
        assert np.array_equal(load_image(tmp_path / "unused.png"), plain)


# --- where the measurement benchmarks look for their data ---------------------------------------------

def test_measure_emps_looks_beside_the_repository_and_says_so_when_the_folder_is_absent(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("BMCTL_EMPS", raising=False)
    mod = load_benchmark("measure_emps")
    assert mod.EMPS == ROOT.parent / "shared" / "data" / "emps-dev"  # not a path of one machine
    monkeypatch.setattr(mod, "emps_rows", lambda *a, **k: pytest.fail("measured"))
    (tmp_path / "empty").mkdir()
    for folder, why in ((tmp_path / "absent", "no such folder"), (tmp_path / "empty", "no NAME.seg.png masks in it")):
        assert mod.main(["--emps", str(folder), "--name", "never_written"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"measure_emps: {folder}: {why}") and "BMCTL_EMPS" in err[0], err
    monkeypatch.setenv("BMCTL_EMPS", str(tmp_path / "elsewhere"))
    assert load_benchmark("measure_emps").EMPS == tmp_path / "elsewhere"


def test_measure_emps_in_a_git_worktree_looks_beside_the_main_checkout(tmp_path):
    """The baseline runs copy the script into a worktree of an older commit (/tmp/base): it finds the
    same data as in the main checkout."""
    mod = load_benchmark("measure_emps")
    wt = tmp_path / "base"
    wt.mkdir()
    (wt / ".git").write_text("gitdir: /somewhere/main/.git/worktrees/base\n", encoding="utf-8")
    assert mod._main_checkout(wt) == Path("/somewhere/main")
    (wt / ".git").write_text("gitdir: ../main/.git/worktrees/base\n", encoding="utf-8")  # relative to the worktree
    assert mod._main_checkout(wt) == tmp_path / "main"
    assert mod._main_checkout(tmp_path) == tmp_path  # not a worktree: the folder itself


def test_measure_accuracy_looks_beside_the_repository_and_says_so_when_the_folder_is_absent(tmp_path, monkeypatch,
                                                                                            capsys):
    monkeypatch.delenv("BMCTL_MICROGRAPHS", raising=False)
    mod = load_benchmark("measure_accuracy")
    assert mod.MICROGRAPHS == ROOT.parent / "shared" / "data" / "micrographs"
    monkeypatch.setattr(mod, "ROOT", tmp_path)  # no tests/data here ...
    monkeypatch.setattr(mod, "MICROGRAPHS", tmp_path / "absent")  # ... nor the shared folder
    monkeypatch.setattr(mod, "RUN", {})  # nothing may run ...
    monkeypatch.setattr(mod, "write_results", lambda *a, **k: pytest.fail("written"))  # ... nor be written
    assert mod.main(["real"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"not found in tests/data or {tmp_path / 'absent'}, no such folder" in err[0], err
    assert "BMCTL_MICROGRAPHS" in err[0] and "nothing measured" in err[0]
    monkeypatch.setenv("BMCTL_MICROGRAPHS", str(tmp_path / "elsewhere"))
    assert load_benchmark("measure_accuracy").MICROGRAPHS == tmp_path / "elsewhere"
