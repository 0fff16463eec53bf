"""Pixel size of a micrograph: vendor metadata, the data bar and its scale bar.

Order of precedence (:func:`resolve_scale`): ``um_per_px`` (``--um-per-px``) given by the user,
then the pixel size stored by the instrument in the TIFF (:func:`scale_from_metadata`), then a
scale bar found in the image when the user gives its length (``scale_bar_um``, ``--scale-bar-um``;
:func:`find_scale_bar`); messages name them as the caller spells them (:func:`scale_help`).
Supported metadata (``docs/measurement.md`` §8.1):

* FEI/Thermo Fisher (Helios, Quanta, Nova, Scios, Apreo, ...): TIFF tag 34682 ``FEI_HELIOS``,
  ``[Scan] PixelWidth`` in metres;
* FEI/Philips XL series: TIFF tag 34680 ``FEI_SFEG``; it stores no pixel size, only the
  magnification and the display it refers to, so the pixel size is *derived*: horizontal field
  width = display width (``ImageDevice.SizeY`` x ``RatioXY``, mm) / magnification, divided by
  the image width in px (an assumption, checked against the scale bar on the shipped image);
* Zeiss SmartSEM: TIFF tag 34118 ``CZ_SEM``, ``AP_PIXEL_SIZE`` ("Image Pixel Size", with unit);
* TESCAN: TIFF tag 50431, text ``PixelSizeX=`` in metres;
* JEOL: the sidecar ``IMAGE.txt`` with ``$$SM_MICRON_BAR`` (bar length, px) and
  ``$$SM_MICRON_MARKER`` (its length, e.g. ``5um``);
* ImageJ-calibrated TIFF: ``unit=`` in the ImageDescription and XResolution (px per unit);
* plain TIFF XResolution/ResolutionUnit (cm or inch) only when it is physical, i.e. the pixel
  is <= 10 um; print resolutions (72-600 dpi, >= 42 um per px) are ignored.

The data bar (info strip) of SEM images is a band of rows near the bottom (or, as some
instruments write it, a banner at the top) in which most pixels have one value (the strip's
fill); :func:`find_info_bar` finds its first row (or a banner's last row).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError
from ..naming import arg

#: sane pixel sizes: 0.1 nm (a TEM) to 1 mm (a photograph of a sieve) per px
UM_PER_PX_RANGE = (1e-4, 1e3)
MAX_PHYSICAL_UM_PER_PX = 10.0  # larger "pixel sizes" in XResolution are print/screen dpi
INFO_BAR_SEARCH = 0.35  # share of the image height searched for a data bar (from the bottom; from the top for a banner)
INFO_BAR_FLAT_SHARE = 0.5  # a data-bar row: at least this share of its pixels has the modal value ...
INFO_BAR_EXTREME = 0.03  # ... or lies within this share of the image range of its darkest or brightest value
INFO_BAR_MIN_ROWS = 4
SCALE_BAR_MIN_PX = 20
SCALE_BAR_ASPECT = 3.0  # a bar is at least this many times longer than thick
SCALE_BAR_FULL = 0.95  # a row of the bar is ink over at least this share of the run (a noisy or compressed bar)
SCALE_BAR_THIN_PX = 10  # a thicker bar must also be uniform (drawn, not image content)
SCALE_BAR_AROUND = 0.3  # at most this share of the 3 rows above and below a bar is ink
SCALE_BAR_SET_OFF = 0.3  # a bar differs from the rows above and below it by this share of the image range
SCALE_BAR_SATURATION = 0.03  # marks drawn in an extreme value: within this share of the range of it
SCALE_BAR_BOX_EXTENT = 0.88  # a box drawn in an extreme value: its hole-filled area / its bounding box


@dataclass(frozen=True)
class Scale:
    """A pixel size and where it came from.

    Attributes
    ----------
    um_per_px : float
        Pixel size in micrometres.
    source : str
        ``"user"``, ``"metadata"`` or ``"scale-bar"``.
    detail : str
        What was read (tag, values, assumption), for the user.
    """

    um_per_px: float
    source: str
    detail: str


@dataclass(frozen=True)
class ScaleBar:
    """A horizontal scale bar found in the image.

    Attributes
    ----------
    length_px : float
        Bar length in px (between the centres of its end ticks when it has ticks).
    row : int
        Image row of the bar.
    x0, x1 : int
        First and last column of the bar's run.
    y0, y1 : int or None
        First and last image row of the bar (its thickness); ``None``: not recorded.
    """

    length_px: float
    row: int
    x0: int
    x1: int
    y0: int | None = None
    y1: int | None = None


def _unit_to_um(unit: str) -> float | None:
    u = unit.strip().lower().replace("µ", "u").replace("μ", "u")
    return {"m": 1e6, "mm": 1e3, "um": 1.0, "micron": 1.0, "microns": 1.0, "nm": 1e-3, "pm": 1e-6}.get(u)


def _fei_helios(value) -> tuple[float, str] | None:
    if isinstance(value, dict):
        for section in ("Scan", "EScan", "IScan"):
            px = value.get(section, {}).get("PixelWidth") if isinstance(value.get(section), dict) else None
            if px:
                return float(px) * 1e6, f"FEI/Thermo tag 34682 [{section}] PixelWidth = {float(px):.6g} m"
        return None
    m = re.search(r"\[Scan\][^\[]*?PixelWidth\s*=\s*([0-9.eE+-]+)", str(value))
    return (float(m.group(1)) * 1e6, f"FEI/Thermo tag 34682 [Scan] PixelWidth = {m.group(1)} m") if m else None


def _fei_xl(value, width_px: int) -> tuple[float, str] | None:
    if not isinstance(value, dict):
        return None
    mag = (value.get("Vector") or {}).get("Magnification")
    dev = value.get("ImageDevice") or {}
    size_y, ratio = dev.get("SizeY"), dev.get("RatioXY")
    if not (mag and size_y and ratio):
        return None
    hfw_um = float(size_y) * float(ratio) * 1e3 / float(mag)  # display width (mm) / magnification
    return hfw_um / width_px, (
        f"FEI/Philips XL tag 34680: magnification {float(mag):g} on a display {float(size_y):g} mm x {float(ratio):g} "
        f"wide -> field width {hfw_um:.4g} µm over {width_px} px (assumes the image spans the display width)"
    )


def _zeiss(value) -> tuple[float, str] | None:
    if isinstance(value, dict):
        for key, item in value.items():
            if key in ("ap_pixel_size", "ap_image_pixel_size") or (isinstance(item, tuple) and item and item[0] == "Image Pixel Size"):
                if isinstance(item, tuple) and len(item) >= 3 and _unit_to_um(str(item[2])):
                    return float(item[1]) * _unit_to_um(str(item[2])), f"Zeiss tag 34118 Image Pixel Size = {item[1]} {item[2]}"
        return None
    m = re.search(r"Image Pixel Size\s*=\s*([0-9.eE+-]+)\s*(\w+)", str(value))
    if m and _unit_to_um(m.group(2)):
        return float(m.group(1)) * _unit_to_um(m.group(2)), f"Zeiss tag 34118 Image Pixel Size = {m.group(1)} {m.group(2)}"
    return None


def _tescan(value) -> tuple[float, str] | None:
    text = value.decode("latin-1", "replace") if isinstance(value, bytes) else str(value)
    m = re.search(r"PixelSizeX\s*=\s*([0-9.eE+-]+)", text)
    return (float(m.group(1)) * 1e6, f"TESCAN tag 50431 PixelSizeX = {m.group(1)} m") if m else None


def _jeol_sidecar(path: Path) -> tuple[float, str] | None:
    side = path.with_suffix(".txt")
    if not side.is_file():
        return None
    from ..io import read_input_bytes

    text = read_input_bytes(side, max_bytes=1 << 20).decode("latin-1", errors="replace")  # bounded, regular
    bar = re.search(r"\$\$?SM_MICRON_BAR\s+([0-9.]+)", text)
    marker = re.search(r"\$\$?SM_MICRON_MARKER\s+([0-9.]+)\s*([a-zA-Zµμ]+)", text)
    if not (bar and marker and _unit_to_um(marker.group(2)) and float(bar.group(1)) > 0):
        return None
    um = float(marker.group(1)) * _unit_to_um(marker.group(2))
    return um / float(bar.group(1)), f"JEOL {side.name}: marker {marker.group(1)} {marker.group(2)} = {bar.group(1)} px"


def _resolution(tags, description: str) -> tuple[float, str] | None:
    xres = tags.get(282)
    if xres is None:
        return None
    num, den = xres.value if isinstance(xres.value, tuple) else (xres.value, 1)
    px_per_unit = float(num) / float(den) if den else 0.0
    if px_per_unit <= 0:
        return None
    m = re.search(r"unit=(\S+)", description or "")
    if "ImageJ=" in (description or "") and m and _unit_to_um(m.group(1).replace("\\u00B5", "u")):
        return _unit_to_um(m.group(1).replace("\\u00B5", "u")) / px_per_unit, f"ImageJ calibration: {px_per_unit:g} px per {m.group(1)}"
    unit = tags.get(296)
    um_per_unit = {2: 25400.0, 3: 10000.0}.get(int(unit.value) if unit is not None else 2)
    if um_per_unit is None:
        return None
    um = um_per_unit / px_per_unit
    if um > MAX_PHYSICAL_UM_PER_PX:
        return None  # a print/screen resolution, not the pixel size
    return um, f"TIFF XResolution {px_per_unit:g} px per {'inch' if um_per_unit > 20000 else 'cm'}"


def scale_from_metadata(path: str | os.PathLike) -> Scale | None:
    """The pixel size stored by the instrument, or ``None`` if the file has none we can read.

    Parameters
    ----------
    path : path-like
        Image file (TIFF tags are read with ``tifffile``; JEOL uses a ``.txt`` sidecar).

    Returns
    -------
    Scale or None
    """
    from .loading import is_tiff, quiet_tifffile

    path = Path(path)
    found = None
    if is_tiff(path):  # by its first bytes: a TIFF renamed .png keeps its instrument's pixel size
        import tifffile

        try:
            with quiet_tifffile(), tifffile.TiffFile(path) as tif:
                page = tif.pages[0]
                tags = page.tags
                width = int(page.shape[-1] if page.ndim == 2 else page.shape[1])
                desc = page.description or ""
                for code, reader in ((34682, _fei_helios), (34118, _zeiss), (50431, _tescan)):
                    if found is None and code in tags:
                        found = reader(tags[code].value)
                if found is None and 34680 in tags:
                    found = _fei_xl(tags[34680].value, width)
                if found is None:
                    found = _jeol_sidecar(path)
                if found is None:
                    found = _resolution(tags, desc)
        except (tifffile.TiffFileError, OSError, ValueError, KeyError, TypeError):
            found = None
    else:
        found = _jeol_sidecar(path)
    if found is None or not np.isfinite(found[0]) or found[0] <= 0:
        return None
    return Scale(float(found[0]), "metadata", found[1])


# --- data bar and scale bar -----------------------------------------------------------------------

def _modal_share(row: np.ndarray) -> tuple[float, float]:
    vals, counts = np.unique(row, return_counts=True)
    k = int(np.argmax(counts))
    return float(counts[k]) / row.size, float(vals[k])


def _flat_rows(img: np.ndarray, rows: range) -> np.ndarray:
    """Whether each of ``rows`` is a data-bar row: at least ``INFO_BAR_FLAT_SHARE`` of its pixels
    have its modal value, or lie within ``INFO_BAR_EXTREME`` of the image range of the image's
    darkest value, or of its brightest (a black or white fill that JPEG compression or blurring
    has spread over a few levels next to the text)."""
    lo, hi = float(img.min()), float(img.max())
    tol = INFO_BAR_EXTREME * (hi - lo)
    band = img[rows.start:rows.stop]
    near = np.maximum((band <= lo + tol).mean(axis=1), (band >= hi - tol).mean(axis=1))
    modal = np.array([_modal_share(row)[0] for row in band])
    return (modal >= INFO_BAR_FLAT_SHARE) | (near >= INFO_BAR_FLAT_SHARE)


def _bar_run(flat: np.ndarray) -> int | None:
    """Index of the first element of the first run of at least ``INFO_BAR_MIN_ROWS`` true values
    that follows a false one (a run from index 0 on is not a bar: it has no inner edge)."""
    run, edge = 0, False
    for i, f in enumerate(flat):
        if not f:
            run, edge = 0, True
        elif edge:
            run += 1
            if run >= INFO_BAR_MIN_ROWS:
                return i - run + 1
    return None


def find_info_bar(img: np.ndarray, side: str = "bottom") -> int | None:
    """First row of the data bar (info strip) at the bottom of an SEM image, or ``None``; with
    ``side="top"``, the last row of a data bar at the top of the image (a banner).

    A data-bar row has one value (the strip's fill) in at least ``INFO_BAR_FLAT_SHARE`` of its
    pixels, which a noisy micrograph row never has: its modal value, or (a black or white fill
    spread by JPEG compression or blurring) a value within ``INFO_BAR_EXTREME`` of the image
    range of the image's darkest or brightest value (:func:`_flat_rows`). The bar is the run of
    at least ``INFO_BAR_MIN_ROWS`` such rows nearest the image's middle that begins within the
    outer ``INFO_BAR_SEARCH`` of the image (the row on its inner side is not a data-bar row: a
    flat background reaching into the band is no bar): at the bottom its topmost such run,
    everything from it to the bottom edge excluded; at the top the bottommost, everything from
    the top edge to it excluded.

    Parameters
    ----------
    img : ndarray of float, shape (H, W)
    side : {"bottom", "top"}, optional

    Returns
    -------
    int or None
        Bottom: the first excluded row. Top: the last excluded row.
    """
    if side not in ("bottom", "top"):
        raise ValueError(f"side must be 'bottom' or 'top' (got {side!r})")
    h = img.shape[0]
    n = h - int(h * (1.0 - INFO_BAR_SEARCH))  # rows searched at either edge
    if n >= h:
        return None
    if side == "top":  # rows n (the one below the band) up to 0
        i = _bar_run(_flat_rows(img, range(0, n + 1))[::-1])
        return None if i is None or n - i >= h - 9 else n - i
    start = h - n  # rows start - 1 (the one above the band) down to h - 1
    i = _bar_run(_flat_rows(img, range(start - 1, h)))
    return None if i is None or start - 1 + i <= 8 else start - 1 + i


def _bar_in(img: np.ndarray, y0: int, ink: np.ndarray, span: float) -> ScaleBar | None:
    """The longest run of ``ink`` (rows ``y0`` on of ``img``) if it is a scale bar, else ``None``.

    A bar: at least ``SCALE_BAR_MIN_PX`` long; its thickness (the contiguous rows inked over at
    least ``SCALE_BAR_FULL`` of the run) at most ``SCALE_BAR_THIN_PX`` or 1/``SCALE_BAR_ASPECT`` of its length; less than ``SCALE_BAR_AROUND`` of
    the 3 rows above and below it inked; and set off from both: the median of each differs from
    the bar's by at least ``SCALE_BAR_SET_OFF`` of the image range (not the edge of a brighter
    or darker object). A bar thicker than ``SCALE_BAR_THIN_PX`` is also uniform (drawn): the
    spread of its inner pixels is at most ``SCALE_BAR_SET_OFF`` of the range.
    """
    best = None
    for y in range(ink.shape[0]):
        lab, n = ndi.label(ink[y])
        if n == 0:
            continue
        sizes = np.bincount(lab)[1:]
        k = int(np.argmax(sizes))
        if sizes[k] >= SCALE_BAR_MIN_PX and (best is None or sizes[k] > best[0]):
            xs = np.nonzero(lab == k + 1)[0]
            best = (int(sizes[k]), y, int(xs[0]), int(xs[-1]))
    if best is None:
        return None
    n, y, x0, x1 = best
    full = ink[:, x0:x1 + 1].mean(axis=1) >= SCALE_BAR_FULL
    t0, t1 = y, y
    while t0 > 0 and full[t0 - 1]:
        t0 -= 1
    while t1 + 1 < full.size and full[t1 + 1]:
        t1 += 1
    if t1 - t0 + 1 > SCALE_BAR_THIN_PX and SCALE_BAR_ASPECT * (t1 - t0 + 1) > n:
        return None  # thick and short: a block, not a bar
    around = np.r_[ink[max(t0 - 3, 0):t0, x0:x1 + 1].ravel(), ink[t1 + 1:t1 + 4, x0:x1 + 1].ravel()]
    if around.size and around.mean() > SCALE_BAR_AROUND:
        return None  # ink all around it: a bright object, not a bar
    a0, a1 = y0 + t0, y0 + t1  # image rows
    body = img[a0:a1 + 1, x0:x1 + 1]
    level = float(np.median(body))
    for side in (img[max(a0 - 3, 0):a0, x0:x1 + 1], img[a1 + 1:a1 + 4, x0:x1 + 1]):
        if side.size and abs(float(np.median(side)) - level) < SCALE_BAR_SET_OFF * span:
            return None  # the edge of an object as bright or dark as the bar
    if t1 - t0 + 1 > SCALE_BAR_THIN_PX:
        inner = body[1:-1, 1:-1]
        q25, q75 = np.quantile(inner, [0.25, 0.75])
        if q75 - q25 > SCALE_BAR_SET_OFF * span:
            return None  # textured: image content, not a drawn bar

    def tick_width(cols):
        wdt = 0
        for x in cols:
            col = ink[:, x]
            if (t0 >= 2 and col[t0 - 2]) or (t1 + 2 < col.size and col[t1 + 2]):
                wdt += 1
            else:
                break
        return wdt

    wl, wr = tick_width(range(x0, x1 + 1)), tick_width(range(x1, x0 - 1, -1))
    if wl >= n // 2 or wr >= n // 2:
        wl = wr = 0
    return ScaleBar(float(n - 0.5 * (wl + wr)), y0 + y, x0, x1, a0, a1)


def _drawn_inks(region: np.ndarray, lo: float, hi: float, span: float):
    """Ink masks of marks drawn in the image's extreme values: the pixels at each extreme (a bar
    drawn in it), and inside each box drawn in it (a filled rectangle holding marks) the pixels
    far from the box's value (a bar drawn on the box)."""
    tol = max(SCALE_BAR_SATURATION * span, 1.5 / 255)
    for extreme in (hi, lo):
        sat = np.abs(region - extreme) <= tol
        yield sat
        lab, n = ndi.label(sat)
        for i, sl in enumerate(ndi.find_objects(lab), start=1):
            if sl is None or sl[1].stop - sl[1].start < SCALE_BAR_MIN_PX:
                continue
            h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
            own = lab[sl] == i
            box = ndi.binary_fill_holes(own)
            if box.sum() < SCALE_BAR_BOX_EXTENT * h * w or box.sum() <= own.sum():
                continue  # not a filled rectangle holding something
            ink = np.zeros(region.shape, bool)
            ink[sl] = box & ~own & (np.abs(region[sl] - extreme) > 0.5 * span)
            yield ink


def find_scale_bar(img: np.ndarray, top: int | None = None, banner: int | None = None) -> ScaleBar | None:
    """The longest straight horizontal bar of strongly contrasting pixels below row ``top``.

    Searched in the data bar when there is one (``top`` = its first row), else in a data bar at
    the top of the image (``banner`` = its last row) and, when that gives none, in the bottom
    quarter of the image. First among the pixels that differ from the region's modal (fill)
    value by more than half the image range; when that gives no bar, among the marks drawn in
    the image's extreme values (within ``SCALE_BAR_SATURATION`` of the range), and inside each
    box drawn in one of them (a white label box holding a black bar), the longest bar there.
    A bar may be thick (its length at least ``SCALE_BAR_ASPECT`` times its thickness) and must be
    set off from the rows above and below it (:func:`_bar_in`). Its length is the run length,
    less half the width of each end tick (vertical strokes at the ends taller than the bar),
    i.e. the distance between tick centres.

    Returns
    -------
    ScaleBar or None
        ``None`` when no run of at least ``SCALE_BAR_MIN_PX`` px is a bar.
    """
    h, w = img.shape
    if top is None and banner is not None:
        bar = _scale_bar_in(img, 0, banner + 1)
        if bar is not None:
            return bar
    return _scale_bar_in(img, top if top is not None else int(0.75 * h), h)


def _scale_bar_in(img: np.ndarray, y0: int, y1: int) -> ScaleBar | None:
    """:func:`find_scale_bar` in rows ``y0:y1`` of ``img``."""
    region = img[y0:y1]
    if region.size == 0:
        return None
    span = float(np.ptp(img) or 1.0)
    fill = _modal_share(region.ravel())[1]
    bar = _bar_in(img, y0, np.abs(region - fill) > 0.5 * span, span)
    if bar is not None:
        return bar
    found = [b for ink in _drawn_inks(region, float(img.min()), float(img.max()), span)
             if (b := _bar_in(img, y0, ink, span)) is not None]
    return max(found, key=lambda b: (b.x1 - b.x0, -b.row)) if found else None


def nearest_125(value: float) -> float:
    """The nearest number of the 1-2-5 series (scale-bar lengths), e.g. 4.9 -> 5."""
    if value <= 0:
        return value
    e = np.floor(np.log10(value))
    cands = np.array([1, 2, 5, 10]) * 10.0**e
    return float(cands[np.argmin(np.abs(np.log(cands / value)))])


def scale_help(bar: bool = True) -> str:
    """How to give a pixel size, naming the arguments as the caller spells them
    (:func:`bmctl.naming.arg`): ``um_per_px`` and, with ``bar``, ``scale_bar_um``; within
    :func:`bmctl.naming.naming` (``bmctl measure``) the flags.

    Parameters
    ----------
    bar : bool, optional
        Also name the scale bar's length as a way.

    Examples
    --------
    >>> scale_help()
    "give the scale with um_per_px X, or scale_bar_um L (the length written on the image's scale bar)"
    >>> from bmctl.naming import naming
    >>> with naming({"um_per_px": "--um-per-px"}):
    ...     scale_help(bar=False)
    'give the scale with --um-per-px X'
    """
    way = f"give the scale with {arg('um_per_px')} X"
    return f"{way}, or {arg('scale_bar_um')} L (the length written on the image's scale bar)" if bar else way


def resolve_scale(path, img: np.ndarray, *, um_per_px=None, scale_bar_um=None, info_top=None,
                  info_banner=None) -> tuple[Scale, ScaleBar | None]:
    """The pixel size to use for one image, and the scale bar found (if any).

    Parameters
    ----------
    path : path-like or None
        Image file (for metadata); ``None`` for arrays.
    img : ndarray of float
        The full image.
    um_per_px : float, optional
        User override.
    scale_bar_um : float, optional
        Length of the image's scale bar in um; used when there is no user scale and no metadata.
    info_top : int, optional
        First row of the data bar (where the scale bar is searched).
    info_banner : int, optional
        Last row of a data bar at the top of the image (searched when ``info_top`` is None).

    Returns
    -------
    Scale, ScaleBar or None

    Raises
    ------
    bmctl.errors.InputError
        No scale can be found, or the one found in the metadata or from the scale bar is outside
        :data:`UM_PER_PX_RANGE`; the message says where it came from and how to give one.
    """
    bar = find_scale_bar(img, info_top, info_banner)
    if um_per_px is not None:
        # the detail is recorded (measure.json): the same words from Python as from `bmctl measure`
        return Scale(float(um_per_px), "user", "--um-per-px"), bar
    name = str(path) if path is not None else "image"
    meta = scale_from_metadata(path) if path is not None else None
    if meta is not None:
        return _sane(meta, name, "the image metadata", scale_help(bar=False)), bar
    if scale_bar_um is not None:
        if bar is None:
            raise InputError(f"{name}: {arg('scale_bar_um')} given but no scale bar found; {scale_help(bar=False)}")
        read = f"scale bar {bar.length_px:g} px at row {bar.row} = {float(scale_bar_um):g} µm"
        found = Scale(float(scale_bar_um) / bar.length_px, "scale-bar", f"{read} (--scale-bar-um)")
        return _sane(found, name, "the scale bar", f"check {arg('scale_bar_um')}, or {scale_help(bar=False)}",
                     f"{read} ({arg('scale_bar_um')})"), bar
    raise InputError(f"{name}: no pixel size in the image metadata; {scale_help()}")


def _sane(scale: Scale, name: str, source: str, remedy: str, detail: str | None = None) -> Scale:
    """``scale`` if its pixel size lies in :data:`UM_PER_PX_RANGE` (the range ``um_per_px`` is held
    to), else :class:`InputError` naming where it came from (``detail``, default the scale's): a
    metadata unit or a bar length read wrong gave particle sizes of kilometres, refused only later as
    a particle outside its range, with the advice to check arguments the user never gave."""
    lo, hi = UM_PER_PX_RANGE
    if not lo <= scale.um_per_px <= hi:
        raise InputError(f"{name}: pixel size from {source}, {scale.um_per_px:g} µm/px, outside [{lo:g}, {hi:g}] µm/px "
                         f"({scale.detail if detail is None else detail}); {remedy}")
    return scale


def check_scale(um_per_px, name: str = "um_per_px") -> float:
    """Validate a pixel size (or, ``name`` ``"scale_bar_um"``, a scale bar's length): a finite
    number in its sane range, else :class:`InputError` naming the argument as the caller spells it
    (:func:`bmctl.naming.arg`; ``bmctl measure``: its flag).

    Parameters
    ----------
    um_per_px : float
        The value given.
    name : str, optional
        The argument as Python spells it: ``"um_per_px"`` (range :data:`UM_PER_PX_RANGE`) or
        ``"scale_bar_um"`` (1e-3 to 1e5 µm).

    Returns
    -------
    float

    Examples
    --------
    >>> check_scale(0.5)
    0.5
    >>> check_scale(-1)
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: um_per_px: must be a finite number > 0 (got -1)
    """
    bar = name == "scale_bar_um"
    name = arg(name)
    try:
        v = float(um_per_px)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a number ({um_per_px!r})") from None
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name}: must be a finite number > 0 (got {um_per_px})")
    lo, hi = (1e-3, 1e5) if bar else UM_PER_PX_RANGE
    if not lo <= v <= hi:
        raise InputError(f"{name}: {v:g} µm is outside the sane range [{lo:g}, {hi:g}] µm")
    return v
