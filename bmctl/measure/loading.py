"""Reading micrographs (gray float in [0, 1]) and crop windows."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import stat
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..naming import arg


#: the largest image read (pixels): a 16-bit SEM frame is <= ~25 Mpx; a small compressed file can
#: claim billions of pixels and exhaust memory when decoded (a decompression bomb)
MAX_PIXELS = 100_000_000
#: Pillow colour modes decoded through Pillow's own conversion to RGB (imageio would hand their
#: raw channels over as if they were RGB(A): a CMYK JPEG read so is uniform)
CONVERTED_MODES = ("CMYK", "YCbCr", "LAB", "HSV")
#: numpy dtype kinds that are pixel values: bool, signed and unsigned integer, real float
PIXEL_KINDS = "biuf"
#: own-range scaling (wider integers, a file's reals) spans the image's darkest to brightest value, but
#: not a handful of pixels far outside the rest (a hot or dead pixel, a stray value in a float
#: export): the core range lies between the k-th darkest and the k-th brightest value, k the larger
#: of ``OUTLIER_PIXELS`` and ``OUTLIER_SHARE`` of the values ...
OUTLIER_PIXELS = 10
OUTLIER_SHARE = 1e-4
#: ... and values further than this share of the core range beyond either end of it are outliers:
#: the range spans the others, the outliers are clipped to its ends (an image without outliers is
#: scaled by its darkest and brightest values as they are)
OUTLIER_REACH = 0.25
#: the EXIF tag of the orientation a camera stored its picture in (applied by :func:`_orient`); EXIF took
#: it from TIFF, whose Orientation tag (274) has the same number and values
EXIF_ORIENTATION = 0x0112
#: why an image with transparent pixels (an alpha channel, or a colour the file declares transparent) is refused
TRANSPARENT = "has transparent pixels (alpha); flatten it first"


@dataclass(frozen=True)
class ImageHeader:
    """What a file's header says, read without decoding the pixels.

    Attributes
    ----------
    pixels : int or None
        Pixels of all pages or frames together (None: unknown).
    images : int or None
        Images in what is read: the pages of a TIFF's first series (colour samples and
        reduced-resolution pages not counted), the frames of a GIF or APNG, one for a camera's
        multi-picture JPEG (None: unknown).
    mode : str or None
        Pillow's colour mode; for a TIFF, ``"CMYK"`` for inks (photometric separated), else None.
    orientation : int or None
        The orientation the file stores its pixels in (2-8: they are shown flipped or rotated; 1 or
        None: as stored): the EXIF orientation of a file read through Pillow, or a TIFF's
        Orientation tag; the pixel count is the same either way.
    colour_key : bool or None
        Whether a file read through Pillow declares a transparent colour (PNG tRNS, a GIF's
        transparent index) without an alpha channel; None: unknown (a TIFF, an unreadable header).
    """

    pixels: int | None = None
    images: int | None = None
    mode: str | None = None
    orientation: int | None = None
    colour_key: bool | None = None


@contextlib.contextmanager
def quiet_tifffile():
    """Silence tifffile's logger inside the block (it prints damaged headers to stderr itself;
    bmctl reports a bad file in one line of its own)."""
    log = logging.getLogger("tifffile")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


#: the first bytes of a TIFF file (classic and BigTIFF, little- and big-endian)
TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
#: the first bytes of a PNG file
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _named_tiff(path: str) -> bool:
    return path.lower().endswith((".tif", ".tiff"))


def is_tiff(path: str | os.PathLike) -> bool:
    """Whether the file holds a TIFF, by its first bytes, not its name (a PNG saved as ``.tif``
    or a TIFF renamed ``.png`` is read as what it holds); the name decides only when the file
    cannot be opened as a regular file."""
    p = os.fspath(path)
    try:  # O_NONBLOCK: a FIFO does not hang the open
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return _named_tiff(p)
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            return _named_tiff(p)
        return fh.read(4) in TIFF_MAGIC


def _tiff_header(path: str) -> ImageHeader:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        pages = tif.pages  # by index: iterating runs forever on a file whose last page links back to a page
        pixels = sum(int(np.prod(pages[i].shape)) for i in range(len(pages)))
        if not tif.series:
            return ImageHeader(pixels, 0)
        # every series is an image (pages written one by one are a series each), but a reduced-resolution
        # preview: tifffile keeps one as a level of the series it belongs to, or flags it (subfiletype 1)
        full = [s for s in tif.series if not int(s.keyframe.subfiletype or 0) & 1] or tif.series[:1]
        images = sum(int(np.prod([n for n, ax in zip(s.shape, s.axes) if ax not in "YXS"])) for s in full)
        first = tif.series[0]
        cmyk = first.keyframe.photometric == tifffile.PHOTOMETRIC.SEPARATED  # tifffile hands over the raw inks
        return ImageHeader(pixels, images, "CMYK" if cmyk else None, _tiff_orientation(first.keyframe))


def _tiff_orientation(page) -> int | None:
    """The Orientation tag of a TIFF page (tifffile hands the pixels over as stored): 2-8 as an
    EXIF orientation, else None."""
    try:
        value = int(page.tags.valueof(EXIF_ORIENTATION, 1))
    except (TypeError, ValueError):  # a damaged tag (several values, not a number): the pixels are shown as stored
        return None
    return value if 2 <= value <= 8 else None


def _bomb_pixels(exc: Exception) -> int | None:
    """The pixel count in Pillow's DecompressionBombError ("Image size (N pixels) exceeds limit ..."), if given."""
    m = re.search(r"\((\d+) pixels\)", str(exc))
    return int(m.group(1)) if m else None


def _too_large(name: str, pixels: int | None) -> InputError:
    got = f"{pixels:,} pixels" if pixels is not None else "more pixels than Pillow opens"
    return InputError(f"{name}: image too large ({got}, limit {MAX_PIXELS:,}); crop or downsample it first")


def _exif_orientation(im) -> int | None:
    """The EXIF orientation the file stores (from the EXIF block read with the header: a PNG is not
    decoded for it), or None."""
    from PIL import Image

    raw = im.info.get("exif")
    if not raw:
        return None
    try:
        exif = Image.Exif()
        exif.load(raw)
        value = int(exif.get(EXIF_ORIENTATION, 1))
    except Exception:  # noqa: BLE001 - a damaged EXIF block: the pixels are shown as stored
        return None
    return value if 2 <= value <= 8 else None


@contextlib.contextmanager
def _pillow_quiet():
    """Pillow's DecompressionBombWarning silenced inside the block: an image over Pillow's warning
    limit (89 Mpx) is refused or read by bmctl's own limits, in one line."""
    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        yield


def _pillow_header(path: str) -> ImageHeader:
    from PIL import Image

    with _pillow_quiet():
        try:
            im = Image.open(path)
        except Image.DecompressionBombError as exc:  # over twice Pillow's limit: far over bmctl's own
            pixels = _bomb_pixels(exc)
            if pixels is None:
                raise
            return ImageHeader(pixels)
        with im:
            frames = max(1, int(getattr(im, "n_frames", 1)))
            images = 1 if im.format == "MPO" else frames  # a camera JPEG's further pictures are previews: its first is read
            keyed = "transparency" in im.info and "A" not in im.mode and "a" not in im.mode
            return ImageHeader(int(im.size[0]) * int(im.size[1]) * frames, images, im.mode, _exif_orientation(im),
                               keyed)


def image_header(path: str) -> ImageHeader:
    """The file's :class:`ImageHeader` (TIFF via tifffile, other formats via Pillow); fields the
    header does not give are None.

    Parameters
    ----------
    path : str
        The image file.
    """
    try:
        with quiet_tifffile():
            return _tiff_header(path) if is_tiff(path) else _pillow_header(path)
    except Exception:  # noqa: BLE001 - unreadable headers are reported by the reader itself
        return ImageHeader()


def image_pixels(path: str) -> int | None:
    """Pixels the file's header claims (all pages of a TIFF), read without decoding; None if unknown."""
    return image_header(path).pixels


def check_header(head: ImageHeader, name: str) -> None:
    """Refuse an image whose header alone rules it out (too many pixels, no image, several pages), naming it."""
    if head.pixels is not None and head.pixels > MAX_PIXELS:
        raise _too_large(name, head.pixels)
    if head.images == 0:
        raise InputError(f"{name}: cannot read image (the file holds no image)")
    if head.images is not None and head.images > 1:
        raise InputError(f"{name}: holds {head.images} images (pages or frames), one image is expected; "
                         f"save the one to measure as a file of its own")


def verify_image(path: str | os.PathLike, name: str) -> None:
    """Refuse a PNG whose chunks do not check out (a truncated or damaged file) without decoding it
    (Pillow's ``verify``: the chunk checksums), and a file Pillow cannot open (not an image, too
    large), so a bad file among several is named before any is measured; other formats are left to
    the reader."""
    from PIL import Image

    p = os.fspath(path)
    if is_tiff(p):
        return
    with _pillow_quiet():
        try:
            im = Image.open(p)
        except Image.DecompressionBombError as exc:
            raise _too_large(name, _bomb_pixels(exc)) from None
        except Image.UnidentifiedImageError:
            raise InputError(f"{name}: cannot read image (not an image file Pillow can read)") from None
        except Exception as exc:  # noqa: BLE001 - Pillow raises OSError, SyntaxError, ValueError ...
            raise InputError(f"{name}: cannot read image ({_damaged(p, exc)})") from None
        with im:
            if im.format != "PNG":
                return
            try:
                im.verify()
            except Exception as exc:  # noqa: BLE001
                raise InputError(f"{name}: cannot read image ({_damaged(p, exc)})") from None


def _damaged(path: str, exc: Exception) -> str:
    """What is wrong with a file Pillow identified but could not read: a PNG is named as one."""
    try:
        with open(path, "rb") as fh:
            png = fh.read(len(PNG_MAGIC)) == PNG_MAGIC
    except OSError:
        png = False
    said = (str(exc).strip().splitlines() or [""])[0] or type(exc).__name__  # a reader's first line only
    return f"a damaged or truncated {'PNG' if png else 'file'}: {said}"


#: the gray levels Pillow decodes a PNG's 2- and 4-bit gray samples to are the samples times these
#: (0-3 to 0-255, 0-15 to 0-255); its transparent gray is given as a sample
GRAY_SCALED = {"L;2": 85, "L;4": 17}
#: how Pillow unpacks a PNG's 16-bit RGB samples: their high bytes (its transparent colour is given in 16 bits)
RGB16 = "RGB;16B"
#: how Pillow unpacks the 16-bit samples of a PNG's colour with alpha, gray with alpha: their high bytes too
RGBA16, LA16 = "RGBA;16B", "LA;16B"
#: an unpacker of the same bytes that keeps each sample's low byte (its second, as a little-endian sample's)
#: where Pillow has one; a 16-bit gray and alpha PNG's four bytes a pixel are unpacked as they are
LOW_BYTES = {RGB16: "RGB;16L", RGBA16: "RGBA;16L", LA16: "RGBA"}


def _transparent_colour(path: str) -> bool:
    """Whether a file read through Pillow has pixels of a colour it declares transparent (PNG's
    tRNS chunk, GIF's transparent index: no alpha channel in the decoded pixels, so
    :func:`_opaque` cannot see them); an alpha channel is checked on the decoded pixels.

    The colour is compared with the file's samples: a 16-bit RGB PNG's in all 16 bits (Pillow
    decodes their high bytes), a 1-, 2- or 4-bit gray PNG's as the levels Pillow decodes them to."""
    from PIL import Image

    with _pillow_quiet():
        try:
            im = Image.open(path)
        except Image.UnidentifiedImageError:  # read by another of imageio's plugins: no colour declared transparent
            return False
    with _pillow_quiet(), im:
        key = im.info.get("transparency")
        if key is None or "A" in im.mode or "a" in im.mode:
            return False
        if im.mode == "P" or isinstance(key, bytes):  # an index, or an alpha per palette entry
            return bool(np.any(np.asarray(im.convert("RGBA"))[..., 3] != 255))
        rawmode = im.tile[0][3] if len(im.tile) == 1 else None  # how the samples are unpacked (before decoding)
        rawmode = rawmode if isinstance(rawmode, str) else None  # a GIF's are (bits, interlace)
        px = np.asarray(im)
        if isinstance(key, tuple):  # an RGB colour
            colour = np.asarray(key, dtype=np.int64)
            if rawmode != RGB16:
                return bool(np.any(_has_colour(px, colour)))
            hit = _has_colour(px, colour >> 8)
            return bool(np.any(hit)) and bool(np.any(hit & _has_colour(_low_bytes(path), colour & 0xFF)))
        if im.mode == "1":  # decoded as bool; Pillow gives the key as 0 or 255
            return bool(np.any(px == bool(key)))
        return bool(np.any(px == key * GRAY_SCALED.get(rawmode, 1)))


def _has_colour(px: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """Where the pixels ``px`` (H, W, C) have the colour ``colour`` in their first channels, (H, W) bool."""
    return np.all(px.reshape(px.shape[:2] + (-1,))[..., :len(colour)] == colour, axis=-1)


def _unpacked(im, rawmode: str) -> np.ndarray:
    """The pixels of ``im`` (opened, not yet decoded) unpacked by Pillow's ``rawmode`` instead of its own."""
    im.tile = [t._replace(args=rawmode) if hasattr(t, "_replace") else (*t[:3], rawmode) for t in im.tile]
    return np.asarray(im)


def _low_bytes(path: str) -> np.ndarray:
    """The low bytes of a 16-bit RGB PNG's samples (H, W, 3) (Pillow decodes their high bytes):
    decoded with Pillow's unpacker of little-endian samples, which takes each sample's second byte."""
    from PIL import Image

    with _pillow_quiet(), Image.open(path) as im:
        return _unpacked(im, LOW_BYTES[RGB16])


def _wide_png(path: str) -> np.ndarray | None:
    """The samples of a 16-bit colour PNG (RGB, RGBA; or gray and alpha) at their full depth, uint16
    (H, W, C): Pillow decodes such samples to their high bytes only, so an image whose detail lies in
    the low bytes (a narrow-range 16-bit export) was measured as a few gray levels, its transparency
    from the alpha's high byte. None for any other file (a 16-bit gray PNG Pillow reads in full), and
    for one Pillow cannot decode (left to the reader, which names what is wrong as for any file)."""
    from PIL import Image

    try:
        return _wide_png_samples(path)
    except Image.DecompressionBombError:
        raise
    except Exception:  # noqa: BLE001 - a damaged file: the reader says so
        return None


def _wide_png_samples(path: str) -> np.ndarray | None:
    from PIL import Image

    with _pillow_quiet():
        im = Image.open(path)
    with _pillow_quiet(), im:
        if im.format != "PNG" or len(im.tile) != 1 or getattr(im, "n_frames", 1) != 1:
            return None
        rawmode = im.tile[0][3]
        if not isinstance(rawmode, str) or rawmode not in LOW_BYTES:
            return None
        if rawmode == LA16:  # gray and alpha (Pillow gives them as RGBA): each pixel's four bytes, big-endian
            b = _unpacked(im, LOW_BYTES[LA16]).astype(np.uint16)
            return np.stack([(b[..., 0] << 8) | b[..., 1], (b[..., 2] << 8) | b[..., 3]], axis=-1)
        hi = np.asarray(im)
    with _pillow_quiet(), Image.open(path) as im:  # decoded again, its samples' low bytes this time
        lo = _unpacked(im, LOW_BYTES[rawmode])
    return (hi.astype(np.uint16) << 8) | lo


def _decode(path: str, head: ImageHeader) -> np.ndarray:
    from PIL import Image
    from skimage import io

    with warnings.catch_warnings(), quiet_tifffile():  # imageio warns while probing plugins on junk files
        warnings.simplefilter("ignore")
        if head.mode in CONVERTED_MODES:
            turned = head.orientation is not None and is_tiff(path)
            with Image.open(_as_stored(path) if turned else path) as im:
                return np.asarray(im.convert("RGB"))
        tiff = is_tiff(path)
        wide = _wide_png(path) if not tiff and head.mode in ("RGB", "RGBA") else None
        if wide is not None:  # a 16-bit colour PNG: read in full, not as Pillow's high bytes
            return wide
        if tiff == _named_tiff(path):
            return io.imread(path)
        if tiff:  # a TIFF under another name: what scikit-image does for a .tif (tifffile, planar colour last)
            import tifffile

            img = tifffile.imread(path)
            if img.ndim > 2 and img.shape[-1] not in (3, 4) and img.shape[-3] in (3, 4):
                img = np.moveaxis(img, -3, -1)
            return img
        import imageio.v3 as iio  # another format named .tif: scikit-image would hand it to tifffile by its name

        return np.asarray(iio.imread(path, plugin="pillow"))


def _as_stored(path: str):
    """A TIFF's bytes with its Orientation tag set to 1, for Pillow to decode: Pillow turns a TIFF
    itself (and garbles one turned a quarter), while :func:`load_image` turns the pixels read as
    stored (:func:`_orient`); the path itself where the first page (Pillow's) has no such tag."""
    import io

    import tifffile

    with quiet_tifffile(), tifffile.TiffFile(path) as tif:
        tag = tif.pages[0].tags.get(EXIF_ORIENTATION)
        if tag is None:
            return path
        at, size, order = tag.valueoffset, tag.valuebytecount, tif.byteorder
    with open(path, "rb") as fh:
        data = bytearray(fh.read())
    data[at:at + size] = (1).to_bytes(size, "little" if order == "<" else "big")
    return io.BytesIO(bytes(data))


def _orient(img: np.ndarray, orientation: int | None) -> np.ndarray:
    """``img`` (H, W) as displayed under its EXIF (or TIFF) orientation (``PIL.ImageOps.exif_transpose``)."""
    steps = {
        2: lambda a: a[:, ::-1],  # mirrored
        3: lambda a: a[::-1, ::-1],  # upside down
        4: lambda a: a[::-1],  # mirrored upside down
        5: lambda a: a.T,  # transposed
        6: lambda a: np.rot90(a, -1),  # stored turned 90° anticlockwise: shown turned back clockwise
        7: lambda a: a[::-1, ::-1].T,  # transversed
        8: lambda a: np.rot90(a, 1),
    }
    step = steps.get(orientation)
    return img if step is None else np.ascontiguousarray(step(img))


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read a micrograph as a 2-D float array in [0, 1] (colour is averaged to gray).

    A palette image is read as its colours; a CMYK (or other Pillow colour space) image is
    converted to RGB by Pillow first; a single-frame GIF is one image; a 16-bit PNG is read at its
    full depth (colour and alpha too, which Pillow alone decodes to 8 bits). An EXIF orientation (a
    camera picture stored turned), or a TIFF's Orientation tag, is applied: the image is measured
    (its data bar found, a crop window placed) as it is displayed.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ndarray of float, shape (H, W)

    Raises
    ------
    bmctl.errors.InputError
        The file is missing, not an image, a stack of several images (pages, frames or TIFF
        series), an image with transparent pixels (an alpha channel or a transparent colour), of a
        pixel type that is not a number (complex), or not a 2-D (gray or colour) image.
    """
    from PIL import Image

    from ..io import check_input_file
    from .names import path_text

    p = os.fspath(path)
    name = path_text(p)
    check_input_file(p)  # a regular file of a sane size (no FIFO, no device)
    head = image_header(p)
    check_header(head, name)
    tiff = is_tiff(p)
    try:
        img = _decode(p, head)
        # the file is opened again only where its header declared a transparent colour (or was not read)
        keyed = not tiff and head.colour_key is not False and _transparent_colour(p)
    except Image.DecompressionBombError as exc:
        raise _too_large(name, _bomb_pixels(exc)) from None
    except Exception as exc:  # imageio/PIL/tifffile raise many types
        verify_image(p, name)  # not an image, a damaged PNG: said as measure says it (measure verified it first)
        raise InputError(f"{name}: cannot read image ({_damaged(p, exc)})") from None
    if keyed:
        raise InputError(f"{name}: {TRANSPARENT}")
    return _orient(as_gray_float(img, name, own_range=True), head.orientation)


def as_gray_float(img, name: str = "image", own_range: bool = False) -> np.ndarray:
    """Convert an array (gray, gray and alpha, RGB or RGBA; any integer, bool or real dtype) to
    gray float in [0, 1].

    8-bit integer images are scaled by their dtype's range, wider integer images (16-bit frames
    of a 10- or 12-bit detector) by their own range; real images are taken as they are, or, with
    ``own_range`` (a file's pixels: a 32-bit float export), by their own range too. An
    alpha channel must be opaque everywhere (it is then dropped); a leading axis of one frame
    (a single-frame GIF) is dropped.

    Parameters
    ----------
    img : array_like
        The pixels, shape (H, W), (H, W, C) with C in 2, 3, 4, or (1, H, W, C).
    name : str, optional
        The file, named in a message.
    own_range : bool, optional
        Scale real pixels over their own range (:func:`load_image` does; an array in memory is
        taken to be gray levels in [0, 1] already).

    Returns
    -------
    ndarray of float, shape (H, W)
    """
    img = np.asarray(img)
    if img.dtype.kind not in PIXEL_KINDS:
        raise InputError(f"{name}: pixel type {img.dtype} is not supported (expected integer or real gray or colour values)")
    if img.ndim == 4 and img.shape[0] == 1:  # one frame of an animation format
        img = img[0]
    elif img.ndim == 3 and img.shape[0] == 1 and img.shape[-1] > 4:  # one gray frame (a GIF, a one-page stack)
        img = img[0]
    if img.ndim == 3 and img.shape[-1] in (2, 3, 4):
        img = _opaque(img, name)
        img = _scale(img, own_range).mean(axis=-1)
    elif img.ndim == 2:
        img = _scale(img, own_range)
    else:
        raise InputError(f"{name}: not a 2-D gray or colour image (shape {img.shape})")
    if img.size == 0 or min(img.shape) < 8:
        raise InputError(f"{name}: image too small (shape {img.shape})")
    if not np.all(np.isfinite(img)):
        raise InputError(f"{name}: image has NaN or infinite pixels")
    return img


def _opaque(img: np.ndarray, name: str) -> np.ndarray:
    """The colour (or gray) channels of ``img`` (H, W, C); an alpha channel (C = 2 or 4) must be opaque."""
    if img.shape[-1] in (1, 3):
        return img
    alpha = img[..., -1]
    full = True if img.dtype.kind == "b" else 1.0 if img.dtype.kind == "f" else np.iinfo(img.dtype).max
    if np.any(alpha != full):
        raise InputError(f"{name}: {TRANSPARENT}")
    return img[..., :-1]


def _own_range(img: np.ndarray) -> tuple[float, float]:
    """The range ``img`` (non-empty, finite) is scaled over: its darkest and brightest values
    leaving out the outliers, those further than ``OUTLIER_REACH`` of the core range (between the
    k-th darkest and the k-th brightest value, :data:`OUTLIER_PIXELS`, :data:`OUTLIER_SHARE`) beyond
    either end of it; so one hot pixel does not change how the rest is scaled."""
    flat = img.ravel()
    n = flat.size
    lo, hi = float(flat.min()), float(flat.max())
    k = min(max(OUTLIER_PIXELS, math.ceil(OUTLIER_SHARE * n)), (n + 1) // 2)
    part = np.partition(flat, (k - 1, n - k))
    core_lo, core_hi = float(part[k - 1]), float(part[n - k])
    reach = OUTLIER_REACH * (core_hi - core_lo)
    if reach <= 0:  # a flat image with a few other pixels: they are its range
        return lo, hi
    if lo < core_lo - reach:
        lo = float(flat[flat >= core_lo - reach].min())
    if hi > core_hi + reach:
        hi = float(flat[flat <= core_hi + reach].max())
    return lo, hi


def _over(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``img`` mapped from [lo, hi] (hi > lo) to [0, 1], values outside clipped."""
    out = (img.astype(float) - lo) / (hi - lo)
    if float(img.min()) < lo or float(img.max()) > hi:
        np.clip(out, 0.0, 1.0, out=out)
    return out


def _scale(img: np.ndarray, own_range: bool = False) -> np.ndarray:
    """8-bit (and bool) pixels over their dtype's range; wider integers (and, with ``own_range``,
    reals) over their own range (:func:`_own_range`); reals otherwise as they are.

    The segmentation's saturation floor is 1.5 grey levels of an 8-bit image: a 16-bit frame of a
    10- or 12-bit detector (or any narrow-range 16-bit frame) scaled by 65,535 spans a few 8-bit
    levels and fell below it (a 10-bit frame of a clean powder came out ``unusable``); a float export
    of a narrow range (0.40-0.45) lost a sixth of its particles the same way. Scaled over its plain
    minimum and maximum, one hot pixel (65,535 in a 10-bit frame, 1e6 in a float export) squeezed
    the whole image into a few grey levels the same way, while the verdict said ``ok``: the range
    leaves out a handful of pixels far outside the rest."""
    if img.dtype.kind == "b":
        return img.astype(float)
    if img.dtype.kind == "f":
        if not own_range or not np.all(np.isfinite(img)):
            return img.astype(float)  # refused by the caller, naming the bad pixels
        lo, hi = _own_range(img) if img.size else (0.0, 0.0)
        return _over(img, lo, hi) if hi > lo else np.clip(img.astype(float), 0.0, 1.0)
    if img.dtype.itemsize > 1 and img.size:
        lo, hi = _own_range(img)
        if hi > lo:
            return _over(img, lo, hi)
    info = np.iinfo(img.dtype)
    return (img.astype(float) - info.min) / (info.max - info.min)


def parse_crop(text: str) -> tuple[int, int, int, int]:
    """Parse ``"Y0:Y1,X0:X1"`` (pixels, Python slice semantics, ends optional) to a tuple.

    An empty start is 0 and an empty end is returned as ``-1``, meaning the image edge
    (resolved by :func:`crop_slices`).

    Examples
    --------
    >>> parse_crop("0:423,:")
    (0, 423, 0, -1)
    """
    m = re.fullmatch(r"\s*(\d*)\s*:\s*(\d*)\s*,\s*(\d*)\s*:\s*(\d*)\s*", text or "")
    if not m:
        raise InputError(f"{arg('crop')}: expected Y0:Y1,X0:X1 in pixels (got {text!r})")
    y0, y1, x0, x1 = (int(g) if g else d for g, d in zip(m.groups(), (0, -1, 0, -1)))
    if (y1 != -1 and y1 <= y0) or (x1 != -1 and x1 <= x0):
        raise InputError(f"{arg('crop')}: empty window {text!r} (need Y0 < Y1 and X0 < X1)")
    return y0, y1, x0, x1


def crop_slices(crop, shape, name: str = "image") -> tuple[slice, slice]:
    """Slices of a crop ``(y0, y1, x0, x1)`` (``-1`` ends: to the edge) checked against ``shape``."""
    y0, y1, x0, x1 = crop
    h, w = shape
    y1 = h if y1 == -1 else y1
    x1 = w if x1 == -1 else x1
    if not (0 <= y0 < y1 <= h and 0 <= x0 < x1 <= w) or min(y1 - y0, x1 - x0) < 8:
        raise InputError(f"{name}: crop {y0}:{y1},{x0}:{x1} does not fit the image ({h} x {w} px)")
    return slice(y0, y1), slice(x0, x1)
