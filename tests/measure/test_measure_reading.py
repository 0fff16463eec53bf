"""How `bmctl measure` reads a micrograph file: pixel values scaled over a range one stray pixel
does not set, transparency, several images in one TIFF, the EXIF orientation, files Pillow will
not open, and pixel sizes read from the file or its scale bar."""

from __future__ import annotations

import json
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from bmctl.errors import InputError
from bmctl.measure.loading import load_image
from bmctl.measure.micrograph import measure_micrograph
from .shapes import discs as _discs, cli as _cli

DATA = Path(__file__).resolve().parents[1] / "data"
TEM = DATA / "065d8e352c.png"  # dark nanoparticles (TEM), 512 x 525 px


def _gray() -> np.ndarray:
    return np.asarray(Image.open(TEM).convert("L"))


def _one_error_line(err: str, name) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"bmctl: error: {name}"), err
    return lines[0]


# --- a few stray pixels do not set the range of a 16-bit or float image ------------------------------

def _ten_bit_hot(g):
    a = g.astype(np.uint16) * 4
    a[5, 5] = 65535  # a hot pixel
    return a


def _float_low(g):
    f = (g / 255).astype(np.float32)
    f[5, 5] = -1e6
    return f


def _float_high(g):
    f = (g / 255).astype(np.float32)
    f[5, 5] = 1e6
    return f


def _offset_dead(g):
    b = g.astype(np.uint16) * 4 + 1000
    b[5, 5] = 0  # a dead pixel below a detector's offset
    return b


STRAY = {"ten-bit-hot": _ten_bit_hot, "float-low": _float_low, "float-high": _float_high, "offset-dead": _offset_dead}


@pytest.mark.parametrize("case", sorted(STRAY))
def test_one_stray_pixel_does_not_rescale_the_image(tmp_path, case):
    """A 16-bit or float image was scaled over its plain minimum and maximum: one stray pixel
    squeezed the rest into a few grey levels (the TEM image gave 45, 56, 43 particles instead of
    31, or none) while the verdict said ok. The stray pixel is clipped; the rest reads as its
    8-bit copy."""
    import tifffile

    g = _gray()
    tifffile.imwrite(tmp_path / "s.tif", STRAY[case](g))
    img = load_image(tmp_path / "s.tif")
    want = (g - float(g.min())) / float(int(g.max()) - int(g.min()))
    keep = np.ones(g.shape, bool)
    keep[5, 5] = False
    assert np.allclose(img[keep], want[keep], atol=1e-6)
    assert img[5, 5] in (0.0, 1.0)


@pytest.mark.parametrize("case", ["ten-bit-hot", "float-high"])
def test_one_stray_pixel_does_not_change_the_count(tmp_path, case):
    import tifffile

    g = _gray()
    tifffile.imwrite(tmp_path / "s.tif", STRAY[case](g))
    ref = measure_micrograph(g, um_per_px=0.01)
    got = measure_micrograph(tmp_path / "s.tif", um_per_px=0.01)
    assert len(ref.table) == 31
    assert len(got.table) == len(ref.table) and got.verdict == ref.verdict


@pytest.mark.parametrize("kind", ["x4", "x16", "x257", "offset", "float", "narrow", "labels"])
def test_an_image_without_stray_pixels_is_scaled_by_its_minimum_and_maximum(tmp_path, kind):
    """What the outlier rule must leave as it was: 10-, 12- and 16-bit frames, an offset
    detector, float exports, a 16-bit label image (few pixels per value)."""
    import tifffile

    g = _gray()
    a = {"x4": lambda: g.astype(np.uint16) * 4, "x16": lambda: g.astype(np.uint16) * 16,
         "x257": lambda: g.astype(np.uint16) * 257, "offset": lambda: g.astype(np.uint16) * 4 + 1000,
         "float": lambda: (g / 255).astype(np.float32),
         "narrow": lambda: (0.40 + 0.05 * (g / 255)).astype(np.float32),
         "labels": lambda: np.asarray(Image.open(DATA / "065d8e352c.seg.png"))}[kind]()
    tifffile.imwrite(tmp_path / "c.tif", a)
    lo, hi = float(a.min()), float(a.max())
    assert np.array_equal(load_image(tmp_path / "c.tif"), (a.astype(float) - lo) / (hi - lo))


# --- transparency stored as a colour (PNG tRNS, GIF) -----------------------------------------------

def _keyed(path: Path) -> None:
    g = _discs()
    mode, ext = path.stem, path.suffix
    if mode == "L":
        Image.fromarray(g).save(path, transparency=int(g[0, 0]))
    elif mode == "RGB":
        Image.fromarray(g).convert("RGB").save(path, transparency=(int(g[0, 0]),) * 3)
    else:  # a palette image, PNG or GIF
        p = Image.fromarray(g).convert("P")
        p.save(path, transparency=int(np.asarray(p)[0, 0]))


@pytest.mark.parametrize("name", ["L.png", "RGB.png", "P.png", "P.gif"])
def test_a_transparent_colour_is_refused_in_one_line(tmp_path, capsys, name):
    """Transparency stored as a colour (PNG tRNS, a GIF's transparent index) was ignored: the
    transparent pixels were measured as their stored value; an alpha channel was refused."""
    _keyed(tmp_path / name)
    with pytest.raises(InputError, match=r"transparent pixels"):
        load_image(tmp_path / name)
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / name), "--um-per-px", "0.5", "--out", str(tmp_path / "o" / "t.csv")])
    assert rc == 2 and "transparent pixels" in _one_error_line(err, tmp_path / name)
    assert not (tmp_path / "o").exists()


def test_a_transparent_colour_no_pixel_has_is_read_as_before(tmp_path):
    g = _discs()
    Image.fromarray(g).save(tmp_path / "k.png", transparency=7)  # no pixel is 7
    assert np.array_equal(load_image(tmp_path / "k.png"), g / 255.0)


# --- a TIFF of several images ---------------------------------------------------------------------

def test_a_tiff_of_two_images_written_one_by_one_is_refused(tmp_path, capsys):
    """Pages written one by one are series of their own: only the first series was counted, and
    its first page measured without a word."""
    import tifffile

    g = _discs()
    with tifffile.TiffWriter(tmp_path / "two.tif") as t:
        t.write(g)
        t.write(255 - g)
    with pytest.raises(InputError, match="holds 2 images"):
        load_image(tmp_path / "two.tif")
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "two.tif"), "--um-per-px", "0.5"])
    assert rc == 2 and "holds 2 images" in _one_error_line(err, tmp_path / "two.tif")


def test_a_reduced_resolution_preview_is_still_ignored(tmp_path):
    import tifffile

    g = _discs()
    with tifffile.TiffWriter(tmp_path / "p.tif") as t:
        t.write(g)
        t.write(g[::4, ::4], subfiletype=1)
    assert np.array_equal(load_image(tmp_path / "p.tif"), g / 255.0)


# --- EXIF orientation -----------------------------------------------------------------------------

@pytest.mark.parametrize("orientation", range(1, 9))
def test_the_exif_orientation_is_applied(tmp_path, orientation):
    """A camera picture stored turned (EXIF orientation 2-8) was measured as stored: a data bar
    on its side was not found and --crop was read in the stored orientation."""
    a = np.asarray(Image.open(TEM).convert("L"))[:100, :160]
    im = Image.fromarray(a)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.save(tmp_path / "o.png", exif=exif)
    shown = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / "o.png"))) / 255.0
    assert np.array_equal(load_image(tmp_path / "o.png"), shown)


def test_a_turned_jpeg_is_measured_and_cropped_as_displayed(tmp_path, capsys):
    g = _gray()
    im = Image.fromarray(np.ascontiguousarray(np.rot90(g, 1)))  # stored a quarter turn anticlockwise ...
    exif = im.getexif()
    exif[0x0112] = 6  # ... and shown turned back
    im.save(tmp_path / "turned.jpg", exif=exif, quality=95)
    img = load_image(tmp_path / "turned.jpg")
    assert img.shape == g.shape and np.abs(img - g / 255.0).mean() < 0.02
    out = tmp_path / "o" / "t.csv"
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "turned.jpg"), "--um-per-px", "0.01", "--crop", "0:500,0:520",
                               "--no-overlay", "--out", str(out)])
    assert rc == 0, err  # 520 columns: the displayed image has 525, the stored one 512
    assert json.loads((out.parent / "measure.json").read_text(encoding="utf-8"))["inputs"][0]["shape_px"] == list(g.shape)


# --- files Pillow will not open -------------------------------------------------------------------

def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width`` x ``height`` gray pixels (its data holds one row)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * (width + 1))) + chunk(b"IEND", b""))


def _jpeg_header(width: int, height: int) -> bytes:
    """A JPEG whose frame header claims ``width`` x ``height`` gray pixels (no picture data)."""
    return (bytes.fromhex("FFD8FFC0000B08") + struct.pack(">HH", height, width) + bytes.fromhex("01011100")
            + bytes.fromhex("FFDA0008010100003F00") + b"\0" * 16 + bytes.fromhex("FFD9"))


@pytest.mark.parametrize("name, data, pixels", [
    ("big.png", _png_header(20_000, 20_000), "400,000,000"),
    ("big.jpg", _jpeg_header(15_000, 15_000), "225,000,000"),
], ids=["png", "jpeg"])
def test_a_file_over_pillows_own_limit_is_too_large_not_damaged(tmp_path, capsys, name, data, pixels):
    """Over twice Pillow's limit (179 Mpx) Pillow refuses to open the file: the header count was
    lost and the file called "a damaged or truncated PNG", a JPEG too."""
    (tmp_path / name).write_bytes(data)
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / name), "--um-per-px", "0.5"])
    line = _one_error_line(err, tmp_path / name)
    assert rc == 2 and f"image too large ({pixels} pixels, limit 100,000,000)" in line and "PNG" not in line


def test_pillows_decompression_bomb_warning_is_not_printed(tmp_path, capsys):
    """A file over Pillow's warning limit (89 Mpx; here a 96 Mpx PNG header) printed Pillow's
    warning, three lines, before bmctl's own one-line answer."""
    (tmp_path / "w.png").write_bytes(_png_header(9_800, 9_800))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        rc, _, err = _cli(capsys, ["measure", str(tmp_path / "w.png"), "--um-per-px", "0.5"])
    assert rc == 2
    _one_error_line(err, tmp_path / "w.png")
    assert not [w for w in seen if issubclass(w.category, Image.DecompressionBombWarning)]


@pytest.mark.parametrize("name", ["arr.npy", "arr.png"])
def test_a_file_that_is_no_image_is_named_so(tmp_path, capsys, name):
    """A numpy file, renamed .png or not, was "a damaged or truncated PNG: cannot identify image file"."""
    np.save(tmp_path / "a.npy", _discs())
    (tmp_path / name).write_bytes((tmp_path / "a.npy").read_bytes())
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / name), "--um-per-px", "0.5"])
    assert rc == 2
    assert _one_error_line(err, tmp_path / name).endswith("cannot read image (not an image file Pillow can read)")


# --- pixel sizes read from the file or its scale bar ------------------------------------------------

def test_a_metadata_pixel_size_outside_the_sane_range_is_refused_naming_the_metadata(tmp_path, capsys):
    """An ImageJ calibration in metres (1 px per m: 1e6 µm/px) was used: the table check then
    refused particle 1 and advised checking --um-per-px and --scale-bar-um, never given."""
    import tifffile

    path = tmp_path / "ij_m.tif"
    tifffile.imwrite(path, _discs(), imagej=True, resolution=(1.0, 1.0), metadata={"unit": "m"})
    rc, _, err = _cli(capsys, ["measure", str(path), "--out", str(tmp_path / "o" / "t.csv")])
    line = _one_error_line(err, path)
    assert rc == 2 and "pixel size from the image metadata, 1e+06 µm/px, outside [0.0001, 1000] µm/px" in line
    assert "--um-per-px" in line and "--scale-bar-um" not in line
    rc, _, err = _cli(capsys, ["measure", str(path), "--um-per-px", "0.5"])  # the user's scale overrides it
    assert rc == 0, err


def test_a_scale_bar_pixel_size_outside_the_sane_range_is_refused_naming_the_bar(tmp_path, capsys):
    """--scale-bar-um 100000 on a 50 px bar gives 2000 µm/px, past the range --um-per-px is held to."""
    from bmctl.measure.scale import resolve_scale

    img = np.full((200, 200), 0.8)
    img[170:173, 50:100] = 0.0  # a 50 px scale bar in the bottom quarter
    with pytest.raises(InputError, match=r"pixel size from the scale bar, 2000 µm/px, outside \[0.0001, 1000\] µm/px"):
        resolve_scale(None, img, scale_bar_um=1e5)
    assert resolve_scale(None, img, scale_bar_um=5.0)[0].um_per_px == pytest.approx(0.1)
    Image.fromarray(np.round(img * 255).astype(np.uint8)).save(tmp_path / "bar.png")
    rc, _, err = _cli(capsys, ["measure", str(tmp_path / "bar.png"), "--scale-bar-um", "100000"])
    line = _one_error_line(err, tmp_path / "bar.png")
    assert rc == 2 and "pixel size from the scale bar, 2000 µm/px" in line and "--scale-bar-um" in line
