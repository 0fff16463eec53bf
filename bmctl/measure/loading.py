"""Reading micrographs (gray float in [0, 1]) and crop windows."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np

from ..errors import InputError


#: the largest image read (pixels): a 16-bit SEM frame is <= ~25 Mpx; a small compressed file can
#: claim billions of pixels and exhaust memory when decoded (a decompression bomb)
MAX_PIXELS = 100_000_000


def image_pixels(path: str) -> int | None:
    """Pixels the file's header claims (all pages of a TIFF), read without decoding; None if unknown."""
    try:
        if path.lower().endswith((".tif", ".tiff")):
            import tifffile

            with tifffile.TiffFile(path) as tif:
                return sum(int(np.prod(pg.shape)) for pg in tif.pages)
        from PIL import Image

        with Image.open(path) as im:
            return int(im.size[0]) * int(im.size[1]) * max(1, getattr(im, "n_frames", 1))
    except Exception:  # noqa: BLE001 - unreadable headers are reported by the reader itself
        return None


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read a micrograph as a 2-D float array in [0, 1] (colour is averaged to gray).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ndarray of float, shape (H, W)

    Raises
    ------
    bmctl.errors.InputError
        The file is missing, not an image, or not a 2-D (gray or colour) image.
    """
    from skimage import io

    p = str(path)
    from ..io import check_input_file

    check_input_file(p)  # a regular file of a sane size (no FIFO, no device)
    n = image_pixels(p)
    if n is not None and n > MAX_PIXELS:
        raise InputError(f"{p}: image too large ({n:,} pixels, limit {MAX_PIXELS:,}); crop or downsample it first")
    try:
        with warnings.catch_warnings():  # imageio warns while probing plugins on junk files
            warnings.simplefilter("ignore")
            img = io.imread(p)
    except Exception as exc:  # imageio/PIL/tifffile raise many types
        raise InputError(f"{p}: cannot read image ({type(exc).__name__})") from None
    return as_gray_float(img, p)


def as_gray_float(img, name: str = "image") -> np.ndarray:
    """Convert an array (gray, RGB or RGBA; any numeric dtype) to gray float in [0, 1].

    Integer images are scaled by their dtype's range; float images are taken as they are.
    """
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        img = img[..., :3].astype(float).mean(axis=-1) if img.dtype.kind == "f" else _scale_int(img[..., :3]).mean(axis=-1)
    elif img.ndim == 2:
        img = img.astype(float) if img.dtype.kind == "f" else _scale_int(img)
    else:
        raise InputError(f"{name}: not a 2-D gray or colour image (shape {img.shape})")
    if img.dtype.kind == "b":
        img = img.astype(float)
    if img.size == 0 or min(img.shape) < 8:
        raise InputError(f"{name}: image too small (shape {img.shape})")
    if not np.all(np.isfinite(img)):
        raise InputError(f"{name}: image has NaN or infinite pixels")
    return img


def _scale_int(img: np.ndarray) -> np.ndarray:
    if img.dtype.kind == "b":
        return img.astype(float)
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
        raise InputError(f"--crop: expected Y0:Y1,X0:X1 in pixels (got {text!r})")
    y0, y1, x0, x1 = (int(g) if g else d for g, d in zip(m.groups(), (0, -1, 0, -1)))
    if (y1 != -1 and y1 <= y0) or (x1 != -1 and x1 <= x0):
        raise InputError(f"--crop: empty window {text!r} (need Y0 < Y1 and X0 < X1)")
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
