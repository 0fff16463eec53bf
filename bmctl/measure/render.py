"""Synthetic micrographs with known particles: the ground truth for the segmentation.

Particles are warped ellipses (:mod:`bmctl.measure.shapes`) of known size s and
true-perimeter aspect ratio r, drawn bright on a dark, unevenly lit background (as SE
images of loose powder), some of them in touching pairs; the image is blurred (PSF),
noised and quantised to 8 bits. Every random choice comes from the ``rng`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from .shapes import Shapes, shapes_for
from .tables import ParticleTable

GAP_PX = 4.0  # clearance between particles that are not meant to touch
OVERLAP_PX = 1.0  # touching pairs: centre distance shortened by this much (a real neck)


@dataclass(frozen=True)
class Micrograph:
    """A rendered micrograph and its ground truth.

    Attributes
    ----------
    image : ndarray of float, shape (H, W), in [0, 1]
    truth : ParticleTable
        Exact area, perimeter, s, r (um) of each placed particle.
    labels : ndarray of int
        Ground-truth labels, particle ``i`` (row i of ``truth``) is ``i + 1``
        (pixel-centre test; in overlaps the later particle wins).
    shapes : Shapes
        The placed shapes, lengths in px.
    centres_px : ndarray, shape (n, 2)
        (row, column) of each shape's centre.
    touching : ndarray of bool
        Whether the particle was placed in contact with another.
    um_per_px : float
    """

    image: np.ndarray
    truth: ParticleTable
    labels: np.ndarray
    shapes: Shapes
    centres_px: np.ndarray
    touching: np.ndarray
    um_per_px: float


def _take(sh: Shapes, idx) -> Shapes:
    return Shapes(sh.s[idx], sh.q[idx], sh.w[idx], sh.k[idx], sh.phase[idx], sh.theta[idx])


def place(sh: Shapes, shape_hw, rng: np.random.Generator, touching: float = 0.25, tries: int = 300):
    """Non-overlapping positions inside the frame; a share ``touching`` placed in contact pairs.

    Parameters
    ----------
    sh : Shapes
        Shapes in px.
    shape_hw : (int, int)
        Image height and width.
    rng : numpy.random.Generator
    touching : float, optional
        Probability that a particle is placed against an earlier, still unpaired one.
    tries : int, optional
        Random positions tried per particle before it is left out.

    Returns
    -------
    kept : ndarray of int
        Indices of the shapes that were placed.
    centres : ndarray, shape (len(kept), 2)
    pair : ndarray of bool
        Placed in contact with another particle.
    """
    h, w = shape_hw
    rmax = sh.rmax
    margin = GAP_PX
    cy, cx, kept, paired = [], [], [], []
    for i in range(len(sh)):
        ok = False
        partner = -1
        unpaired = [j for j, p in enumerate(paired) if not p]
        if unpaired and rng.random() < touching:
            j = unpaired[rng.integers(len(unpaired))]
            jj = kept[j]
            for _ in range(12):
                phi = rng.uniform(0, 2 * np.pi)
                d = float(sh.radius(jj, phi) + sh.radius(i, phi + np.pi)) - OVERLAP_PX
                y, x = cy[j] + d * np.sin(phi), cx[j] + d * np.cos(phi)
                if _fits(y, x, rmax[i], h, w, margin) and _clear(y, x, rmax[i], cy, cx, rmax[kept], skip=j):
                    if _overlap_small(sh, i, y, x, jj, cy[j], cx[j]):
                        ok, partner = True, j
                        break
        if not ok:
            for _ in range(tries):
                y, x = rng.uniform(0, h), rng.uniform(0, w)
                if _fits(y, x, rmax[i], h, w, margin) and _clear(y, x, rmax[i], cy, cx, rmax[kept]):
                    ok = True
                    break
        if ok:
            cy.append(y)
            cx.append(x)
            kept.append(i)
            paired.append(partner >= 0)
            if partner >= 0:
                paired[partner] = True
    return np.array(kept, dtype=int), np.column_stack([cy, cx]) if kept else np.empty((0, 2)), np.array(paired, bool)


def _fits(y, x, R, h, w, margin):
    return margin + R <= y <= h - 1 - margin - R and margin + R <= x <= w - 1 - margin - R


def _clear(y, x, R, cy, cx, rk, skip=-1):
    if not cy:
        return True
    d = np.hypot(np.asarray(cy) - y, np.asarray(cx) - x) - R - np.asarray(rk) - GAP_PX
    if skip >= 0:
        d[skip] = 1.0
    return bool(np.all(d > 0))


def _overlap_small(sh, i, yi, xi, j, yj, xj):
    """Pixel-centre masks of two touching shapes overlap by at most a few px."""
    (si, ci), (sj, cj) = sh.coverage(i, yi, xi, ss=1), sh.coverage(j, yj, xj, ss=1)
    y0, x0 = min(si[0].start, sj[0].start), min(si[1].start, sj[1].start)
    y1, x1 = max(si[0].stop, sj[0].stop), max(si[1].stop, sj[1].stop)
    a = np.zeros((y1 - y0, x1 - x0), bool)
    b = np.zeros_like(a)
    a[si[0].start - y0 : si[0].stop - y0, si[1].start - x0 : si[1].stop - x0] = ci > 0.5
    b[sj[0].start - y0 : sj[0].stop - y0, sj[1].start - x0 : sj[1].stop - x0] = cj > 0.5
    return int((a & b).sum()) <= max(3, 0.02 * min(a.sum(), b.sum()))


def background(shape_hw, rng: np.random.Generator, level: float = 0.15, uneven: float = 0.25) -> np.ndarray:
    """Unevenly lit background: ``level`` + a random linear ramp and a broad bump of total size ``uneven``."""
    h, w = shape_hw
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    ang = rng.uniform(0, 2 * np.pi)
    ramp = np.cos(ang) * xx + np.sin(ang) * yy
    ramp = (ramp - ramp.min()) / max(np.ptp(ramp), 1e-12)
    by, bx = rng.random(2) * [h / max(h, w), w / max(h, w)]
    bump = np.exp(-((yy - by) ** 2 + (xx - bx) ** 2) / (2 * 0.3**2))
    return level + uneven * (0.6 * ramp + 0.4 * bump)


def render_micrograph(
    rng: np.random.Generator,
    *,
    n: int = 40,
    shape: tuple[int, int] = (512, 512),
    s_px=(12.0, 40.0),
    r=(0.0, 0.2),
    k_range=(3, 5),
    shapes: Shapes | None = None,
    touching: float = 0.25,
    contrast=(0.45, 0.65),
    blur_px: float = 1.0,
    noise: float = 0.03,
    uneven: float = 0.25,
    texture: float = 0.04,
    um_per_px: float = 1.0,
) -> Micrograph:
    """Render a synthetic SE-like micrograph of warped ellipses with known s and r.

    Parameters
    ----------
    rng : numpy.random.Generator
        The only source of randomness.
    n : int, optional
        Particles to try to place (those that do not fit are left out).
    shape : (int, int), optional
        Image height and width in px.
    s_px : tuple (float, float) or array_like, optional
        A tuple is a size range in px (``n`` sizes drawn log-uniform); a list or array
        gives the sizes themselves.
    r : tuple (float, float) or array_like, optional
        A tuple is an aspect-ratio range (uniform); a list or array gives the values.
    k_range : (int, int), optional
        Lobe counts of the warped ellipses (:func:`bmctl.measure.shapes.shapes_for`).
    shapes : Shapes, optional
        Explicit shapes in px (overrides n, s_px, r).
    touching : float, optional
        Share of particles placed in contact with another.
    contrast : (float, float), optional
        Range of particle brightness above the background.
    blur_px : float, optional
        Gaussian PSF sigma.
    noise : float, optional
        Additive Gaussian noise sigma (image range 0-1).
    uneven : float, optional
        Amplitude of the uneven illumination.
    texture : float, optional
        Sigma of a smooth texture inside particles.
    um_per_px : float, optional
        Pixel size for the ground-truth table.

    Returns
    -------
    Micrograph

    Examples
    --------
    >>> import numpy as np
    >>> m = render_micrograph(np.random.default_rng(0), n=10, shape=(200, 200))
    >>> m.image.shape, bool(len(m.truth) == m.labels.max())
    ((200, 200), True)
    """
    if shapes is None:
        s_arr = np.asarray(s_px, dtype=float)
        r_arr = np.asarray(r, dtype=float)
        if isinstance(s_px, tuple):
            s_arr = np.exp(rng.uniform(np.log(s_arr[0]), np.log(s_arr[1]), n))
        if isinstance(r, tuple):
            r_arr = rng.uniform(r_arr[0], r_arr[1], n)
        shapes = shapes_for(s_arr, r_arr, rng, k_range=k_range)
    h, w = shape
    kept, centres, pair = place(shapes, shape, rng, touching)
    sh = _take(shapes, kept)
    signal = np.zeros(shape)
    labels = np.zeros(shape, dtype=np.int32)
    tex = ndi.gaussian_filter(rng.normal(0, 1, shape), 2.0)
    tex *= texture / max(tex.std(), 1e-12)
    for i, (y, x) in enumerate(centres):
        (sy, sx), cov = sh.coverage(i, y, x, ss=4)
        c = rng.uniform(*contrast)
        win = signal[sy, sx]
        np.maximum(win, c * cov, out=win)
        lab = labels[sy, sx]
        lab[cov >= 0.5] = i + 1  # ss=4 coverage >= 1/2 ~ pixel-centre test
    img = background(shape, rng, uneven=uneven) + signal + np.where(signal > 0, tex * (signal > 0.2), 0.0)
    if blur_px > 0:
        img = ndi.gaussian_filter(img, blur_px)
    img = img + rng.normal(0.0, noise, shape)
    img = np.round(np.clip(img, 0.0, 1.0) * 255) / 255
    truth = ParticleTable.from_area_perimeter(sh.area * um_per_px**2, sh.perimeter * um_per_px)
    return Micrograph(img, truth, labels, sh, centres, pair, float(um_per_px))
