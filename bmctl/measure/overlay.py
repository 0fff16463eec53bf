"""Overlay PNG: the micrograph with each measured particle's outline and id, so the user sees
what was segmented (and what was excluded: data bar, crop)."""

from __future__ import annotations

import os

import numpy as np
from scipy import ndimage as ndi
from skimage import segmentation

from ..io import pyplot, savefig


def display_levels(image: np.ndarray) -> np.ndarray:
    """The image stretched from its darkest to its brightest pixel to [0, 1], for display: a
    16-bit frame that uses a few hundred of its 65,536 levels, or a float image in counts, would
    otherwise show as one flat gray (or white) and hide the particles the overlay outlines."""
    img = np.asarray(image, dtype=float)
    lo, hi = float(img.min()), float(img.max())
    if not hi > lo:
        return np.clip(img, 0.0, 1.0)
    return (img - lo) / (hi - lo)


def excluded_pixels(shape, excluded_from_row: int | None = None, excluded_to_row: int | None = None,
                    crop=None) -> np.ndarray:
    """Pixels left out of the measurement: a data bar at the bottom (from ``excluded_from_row``) or the
    top (to ``excluded_to_row``), and everything outside ``crop`` (see :func:`write_overlay`).

    Examples
    --------
    >>> int(excluded_pixels((20, 20), crop="5:15,5:15").sum())
    300
    >>> int(excluded_pixels((20, 20), excluded_from_row=18, crop=(0, -1, 10, -1)).sum())
    220
    """
    out = np.zeros(shape, dtype=bool)
    if excluded_from_row is not None:
        out[excluded_from_row:] = True
    if excluded_to_row is not None:
        out[:excluded_to_row + 1] = True
    if crop is not None:
        from .loading import crop_slices, parse_crop

        rows, cols = crop_slices(parse_crop(crop) if isinstance(crop, str) else crop, shape)
        inside = np.zeros(shape, dtype=bool)
        inside[rows, cols] = True
        out |= ~inside
    return out


def write_overlay(path: str | os.PathLike, image: np.ndarray, labels: np.ndarray, offset=(0, 0), ids=None,
                  *, excluded_from_row: int | None = None, scale_bar=None, title: str = "",
                  excluded_to_row: int | None = None, crop=None) -> None:
    """Write the image with particle outlines (yellow) and ids (cyan) as a PNG, atomically.

    Parameters
    ----------
    path : path-like
    image : ndarray of float, shape (H, W)
        The full input image (gray; shown stretched to its own range, :func:`display_levels`).
    labels : ndarray of int
        Particles 1..n in the segmented frame (cropped), placed at ``offset``.
    offset : (int, int), optional
        (row, column) of the frame in ``image``.
    ids : sequence of int, optional
        Id printed for label ``i`` (``ids[i - 1]``); default ``i``.
    excluded_from_row : int, optional
        First row of the excluded data bar (shaded red to the bottom edge).
    scale_bar : bmctl.measure.scale.ScaleBar, optional
        Marked in green when found.
    title : str, optional
    excluded_to_row : int, optional
        Last row of an excluded data bar at the top of the image (shaded red from the top edge).
    crop : str or (int, int, int, int), optional
        The window measured (``--crop``: ``"Y0:Y1,X0:X1"`` or ``(y0, y1, x0, x1)``, ``-1`` ends to
        the edge); everything outside it is shaded red, as the data bar.
    """
    plt = pyplot()
    h, w = image.shape
    rgb = np.repeat(display_levels(image)[..., None], 3, axis=2)
    full = np.zeros((h, w), dtype=labels.dtype)
    oy, ox = offset
    full[oy:oy + labels.shape[0], ox:ox + labels.shape[1]] = labels
    rgb[segmentation.find_boundaries(full, mode="inner")] = (1.0, 0.9, 0.0)
    excluded = excluded_pixels((h, w), excluded_from_row, excluded_to_row, crop)
    rgb[excluded] = 0.6 * rgb[excluded] + 0.4 * np.array([1.0, 0.0, 0.0])  # each excluded pixel shaded once
    scale = max(1.0, 1400.0 / max(h, w))
    fig = plt.figure(figsize=(w * scale / 100.0, h * scale / 100.0), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(rgb, interpolation="nearest")
    ax.set_axis_off()
    n = int(full.max())
    if n:
        idx = np.arange(1, n + 1)
        cy, cx = np.array(ndi.center_of_mass(full > 0, full, idx)).T
        names = ids if ids is not None else idx
        fs = float(np.clip(400.0 / np.sqrt(n + 1), 3.0, 9.0))
        for y, x, k in zip(cy, cx, names):
            ax.text(x, y, str(int(k)), color="cyan", fontsize=fs, ha="center", va="center")
    if scale_bar is not None:
        ax.plot([scale_bar.x0, scale_bar.x1], [scale_bar.row, scale_bar.row], color="lime", lw=2)
    if title:
        ax.text(4, 4, title, color="white", fontsize=9, va="top", ha="left",
                bbox={"facecolor": "black", "alpha": 0.6, "pad": 2})
    savefig(fig, path, dpi=100)
