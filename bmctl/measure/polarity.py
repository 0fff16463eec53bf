"""Particle polarity: are the particles brighter or darker than what surrounds them?

Particles are convex bodies: along their outline the boundary bends around the particle.
At an edge, the iso-intensity line's curvature ``div(grad I / |grad I|)`` is negative where
the bright side is the inside of the bend (a bright blob: the gradient points inwards and
converges) and positive where the dark side is. :func:`polarity_vote` weighs this sign over
the strongest edges of the image (the outlines, not the texture), smoothed at
``SIGMA_PX`` so that pixel noise does not vote but a gap of a few pixels between touching
particles still does. The vote is the share of edge strength that says "bright particles";
0.5 is a tie. Votes closer to 0.5 than ``AMBIGUOUS`` are decided by the segmentation's own
evidence instead (:func:`bmctl.measure.segment.segment`).

Measured on the 40 EMPS micrographs (``benchmarks/measure_emps.py``, docs/measurement.md):
every vote at least ``AMBIGUOUS`` from 0.5 had the sign of the particles' true contrast.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

SIGMA_PX = 2.0  # smoothing before the curvature (pixel noise out, gaps of >= 3 px kept)
EDGE_QUANTILE = 0.97  # the strongest 3 % of edges vote
AMBIGUOUS = 0.1  # |vote - 0.5| below this: decide by the segmentation's evidence


def polarity_vote(img: np.ndarray, valid: np.ndarray | None = None, sigma_px: float = SIGMA_PX,
                  edge_quantile: float = EDGE_QUANTILE) -> float:
    """Share of the strongest edges whose bend says "bright particles on a darker background".

    Parameters
    ----------
    img : ndarray of float, shape (H, W)
        Gray image.
    valid : ndarray of bool, optional
        Pixels that may vote (annotations and excluded areas left out).
    sigma_px : float, optional
        Gaussian smoothing before the gradient.
    edge_quantile : float, optional
        Only edges stronger than this quantile of the gradient magnitude vote.

    Returns
    -------
    float
        In [0, 1]; > 0.5: bright particles, < 0.5: dark particles; 0.5 when nothing votes.

    Examples
    --------
    >>> import numpy as np
    >>> yy, xx = np.mgrid[:128, :128]
    >>> discs = ((yy - 40) ** 2 + (xx - 40) ** 2 < 15 ** 2) | ((yy - 85) ** 2 + (xx - 90) ** 2 < 20 ** 2)
    >>> img = np.where(discs, 0.8, 0.2)
    >>> polarity_vote(img) > 0.9, polarity_vote(1.0 - img) < 0.1
    (True, True)
    """
    valid = np.ones(img.shape, bool) if valid is None else np.asarray(valid, bool)
    sm = ndi.gaussian_filter(np.asarray(img, float), sigma_px)
    gy, gx = np.gradient(sm)
    mag = np.hypot(gx, gy)
    if not valid.any() or float(mag[valid].max()) <= 0.0:
        return 0.5
    inv = 1.0 / np.maximum(mag, 1e-12)
    curvature = np.gradient(gx * inv, axis=1) + np.gradient(gy * inv, axis=0)
    strong = valid & (mag > np.quantile(mag[valid], edge_quantile))
    w = mag[strong]
    if w.size == 0 or w.sum() <= 0:
        return 0.5
    return float(np.sum(w * (curvature[strong] < 0)) / np.sum(w))
