"""16-bit colour PNGs are read at their full depth: Pillow decodes their samples to the high bytes only."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bmctl.errors import InputError
from bmctl.measure.loading import TRANSPARENT, load_image

#: Adam7's passes: (first column, first row, column step, row step)
ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> PNG colour type (gray, gray and alpha, RGB, RGBA)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _filtered(px: np.ndarray) -> bytes:
    """The rows of ``px`` (H, W, C) uint16 as big-endian samples, each after its filter byte: none,
    Sub (minus the pixel before) and Up (minus the row above) in turn."""
    bpp = 2 * px.shape[2]
    raw = [np.frombuffer(px[y].astype(">u2").tobytes(), np.uint8).astype(np.int64) for y in range(px.shape[0])]
    out = []
    for y, b in enumerate(raw):
        if y % 3 == 1:
            before = np.concatenate([np.zeros(bpp, np.int64), b[:-bpp]])
            out.append(b"\x01" + ((b - before) % 256).astype(np.uint8).tobytes())
        elif y % 3 == 2:
            out.append(b"\x02" + ((b - raw[y - 1]) % 256).astype(np.uint8).tobytes())
        else:
            out.append(b"\x00" + b.astype(np.uint8).tobytes())
    return b"".join(out)


def _png16(path, px: np.ndarray, interlaced: bool = False, exif: bytes | None = None) -> Path:
    """A 16-bit PNG of ``px`` (H, W) or (H, W, C) uint16, C = 2 (gray, alpha), 3 (RGB) or 4 (RGBA)."""
    px = px[..., None] if px.ndim == 2 else px
    h, w, c = px.shape
    if interlaced:
        data = b"".join(_filtered(px[y0::dy, x0::dx]) for x0, y0, dx, dy in ADAM7 if h > y0 and w > x0)
    else:
        data = _filtered(px)
    head = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, COLOUR_TYPE[c], 0, 0, int(interlaced)))
    if exif is not None:
        head += _chunk(b"eXIf", exif)
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + head + _chunk(b"IDAT", zlib.compress(data)) + _chunk(b"IEND", b""))
    return Path(path)


def _ramp(h: int = 48, w: int = 64) -> np.ndarray:
    """An RGB image (H, W, 3) uint16 whose samples differ in their low bytes only (high byte 0x34 all over)."""
    y, x = np.mgrid[:h, :w]
    return (0x3400 + np.stack([3 * x + y, 2 * x + 2 * y, x + 3 * y], axis=-1)).astype(np.uint16)


def _expected(colour: np.ndarray) -> np.ndarray:
    """The gray of 16-bit colour samples scaled over their own range: the mean of the scaled channels."""
    c = colour.astype(float)
    return ((c - c.min()) / (c.max() - c.min())).mean(axis=-1)


@pytest.mark.parametrize("interlaced", (False, True))
def test_a_16_bit_rgb_png_is_read_at_full_depth(tmp_path, interlaced):
    """Its high bytes alone (all equal here) were read: a uniform image."""
    px = _ramp()
    got = load_image(_png16(tmp_path / "ramp.png", px, interlaced))
    assert got.shape == px.shape[:2]
    np.testing.assert_allclose(got, _expected(px), atol=1e-12)


def test_a_16_bit_rgb_png_differing_in_high_and_low_bytes(tmp_path):
    rng = np.random.default_rng(1)
    px = rng.integers(1000, 60000, (40, 50, 3)).astype(np.uint16)
    px[0, 0] = (1000, 1000, 1000)  # its own range ends: no pixel far from the rest
    px[0, 1] = (60000, 60000, 60000)
    np.testing.assert_allclose(load_image(_png16(tmp_path / "noise.png", px)), _expected(px), atol=1e-12)


def test_a_16_bit_rgba_png_is_read_at_full_depth_and_its_alpha_checked_in_16_bits(tmp_path):
    px = _ramp()
    opaque = np.concatenate([px, np.full(px.shape[:2] + (1,), 65535, np.uint16)], axis=-1)
    np.testing.assert_allclose(load_image(_png16(tmp_path / "opaque.png", opaque)), _expected(px), atol=1e-12)
    opaque[5, 7, 3] = 65280  # alpha's high byte 255, not opaque: taken for opaque from the high byte
    with pytest.raises(InputError, match=re.escape(TRANSPARENT)):
        load_image(_png16(tmp_path / "almost.png", opaque, interlaced=True))


def test_a_16_bit_gray_and_alpha_png_is_read_at_full_depth_and_its_alpha_checked_in_16_bits(tmp_path):
    gray = _ramp()[..., 0]
    la = np.stack([gray, np.full(gray.shape, 65535, np.uint16)], axis=-1)
    np.testing.assert_allclose(load_image(_png16(tmp_path / "la.png", la)), _expected(gray[..., None]), atol=1e-12)
    np.testing.assert_allclose(load_image(_png16(tmp_path / "la-i.png", la, interlaced=True)),
                               _expected(gray[..., None]), atol=1e-12)
    la[-1, -1, 1] = 65534
    with pytest.raises(InputError, match=re.escape(TRANSPARENT)):
        load_image(_png16(tmp_path / "almost.png", la))


def test_a_16_bit_gray_png_was_and_is_read_at_full_depth(tmp_path):
    gray = _ramp()[..., 1]
    np.testing.assert_allclose(load_image(_png16(tmp_path / "gray.png", gray)), _expected(gray[..., None]),
                               atol=1e-12)


def test_a_16_bit_rgb_png_turned_by_its_exif_orientation(tmp_path):
    exif = Image.Exif()
    exif[0x0112] = 6  # stored turned anticlockwise: shown turned back clockwise
    px = _ramp()
    got = load_image(_png16(tmp_path / "turned.png", px, exif=exif.tobytes()[6:]))  # eXIf holds the TIFF part
    np.testing.assert_allclose(got, np.rot90(_expected(px), -1), atol=1e-12)


def test_an_8_bit_rgb_png_is_read_as_before(tmp_path):
    px = (_ramp() - 0x3400).astype(np.uint8)
    Image.fromarray(px).save(tmp_path / "eight.png")
    np.testing.assert_allclose(load_image(tmp_path / "eight.png"), (px / 255.0).mean(axis=-1), atol=1e-12)
