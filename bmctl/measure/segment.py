"""Segmentation of grayscale micrographs into particles, and their area, perimeter, s and r.

Pipeline (:func:`segment`; ``docs/measurement.md`` gives the reasons and the numbers):

1. crop and/or mask (e.g. an info bar); drawn annotations (panel letters, scale bars, label
   boxes: :mod:`bmctl.measure.annotations`) are masked too; masked pixels count as image border;
2. polarity: particles brighter or darker than their surroundings, from the bend of the
   strongest edges (:mod:`bmctl.measure.polarity`); a near-tie is decided by segmenting both
   ways and keeping the reading with the better reliability verdict, then the one that
   claims fewer particles (:func:`_near_tie`);
3. background flattening: a grey opening (footprint ``background_px``) of a block-min
   downsampled copy, smoothed and subtracted (uneven illumination);
4. Gaussian smoothing (``smooth_px``) and a global threshold (:func:`threshold_level`): the
   valley between the two histogram modes when each side holds at least
   ``VALLEY_MIN_SHARE`` of the pixels, else the background mode plus ``NOISE_K`` times the
   background's noise (a few particles on a dominant background have no second mode);
   pixels at the image's extreme values (saturated, drawn) are left out of the histogram;
   holes filled;
5. separation of touching particles:
   a. thin dark lines inside the foreground (the shadows between overlapping particles)
      are cut (:func:`cut_dark_lines`);
   b. watershed of the distance transform from all its local maxima, then neighbours
      are merged again, widest neck first, where the distance transform on their common
      boundary (the saddle) is at least ``neck_ratio`` times the smaller of their two
      peaks (scale-free: two touching discs have a ratio near 0, a particle split along a
      ridge of its own medial axis near 1) (:func:`split_touching`);
   c. the labels are grown back over the cut lines (:func:`expand_labels_into`);
   d. filled holes shared by two or more particles (the gap enclosed by a ring of touching
      particles) go back to the background (:func:`drop_shared_holes`); a hole inside one
      particle (a pore, a textured interior) stays filled;
6. per-particle boundary refinement: each particle is re-thresholded at the midpoint of
   its own interior and surrounding background levels (:func:`refine_local`), which
   removes the size bias a single global threshold has on small or faint particles;
7. significance: a particle whose median level stands less than ``contrast_z`` robust
   standard deviations above its surrounding background (locally, and against the whole
   background's noise) is texture or noise, not a particle (:func:`drop_faint`);
8. removal of particles touching the image border (or the masked-out area) and of specks
   below ``min_area_px``.

:func:`measure_labels` then takes the area as the pixel count and the perimeter by the
Crofton estimator (4 directions), whose measured |bias| is <= 1.3 % from 7 px across up
and <= 0.2 % from 14 px
(:mod:`bmctl.measure.perimeter`).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi
from skimage import filters, measure, morphology, segmentation, transform
from skimage.feature import peak_local_max

from ..errors import InputError
from .annotations import find_annotations
from .perimeter import DEFAULT_METHOD, perimeter
from .loading import as_gray_float, crop_slices, load_image, parse_crop  # noqa: F401 (re-exported)
from .polarity import AMBIGUOUS, polarity_vote
from .scale import check_scale  # noqa: F401 (re-exported)
from .tables import ParticleTable

MIN_AREA_PX = 30  # ~ 6 px across: the detection limit; r needs >= 10 px (docs/measurement.md)
NECK_RATIO = 0.8
SMOOTH_PX = 0.5
THRESHOLD = "auto"
CUT_PX = 3.0
CUT_CONTRAST = 0.08
REFINE_RING_PX = 4
VALLEY_MIN_SHARE = 0.005  # a histogram side with fewer pixels is a tail (specks, text), not a class
NOISE_K = 3.0  # no valley: threshold at the background mode + 3 background standard deviations
CONTRAST_Z = 3.0  # a particle stands >= 3 robust standard deviations above its background
SATURATION = 0.012  # pixels this close (share of the range) to the extremes stay out of the histogram
POLARITIES = ("auto", "bright", "dark")
VALLEY_SCALES = (1, 2, 4, 8)  # smoothing tried for a histogram valley, in units of smooth_px


# --- steps ----------------------------------------------------------------------------------------

def flatten_background(img: np.ndarray, valid: np.ndarray, background_px: float) -> np.ndarray:
    """Subtract a smooth background estimated below the (bright) particles.

    Grey opening with a disc of diameter ``background_px`` on a block-min downsampled copy
    (factor ~ background_px / 24), Gaussian-smoothed and resized back.

    Parameters
    ----------
    img : ndarray of float
    valid : ndarray of bool
        Pixels to use; the others are filled with the valid median first.
    background_px : float
        Must exceed the largest particle's diameter.

    Returns
    -------
    ndarray of float
        ``img - background`` (same shape).
    """
    work = np.where(valid, img, np.median(img[valid]))
    f = max(1, int(background_px // 24))
    if f > 1:
        h, w = work.shape
        ph, pw = (-h) % f, (-w) % f
        padded = np.pad(ndi.gaussian_filter(work, 1.0), ((0, ph), (0, pw)), mode="edge")
        small = padded.reshape(padded.shape[0] // f, f, padded.shape[1] // f, f).min(axis=(1, 3))
    else:
        small = ndi.gaussian_filter(work, 1.0)
    radius = max(1, int(round(background_px / (2 * f))))
    bg = morphology.opening(small, morphology.disk(radius))
    bg = ndi.gaussian_filter(bg, radius / 2.0, mode="nearest")
    if f > 1:
        bg = transform.resize(bg, (bg.shape[0] * f, bg.shape[1] * f), order=1, mode="edge")[: img.shape[0], : img.shape[1]]
    return img - bg


THRESHOLDS = ("auto", "otsu", "li", "minimum", "triangle")


def background_mode(vals: np.ndarray) -> tuple[float, float]:
    """Level and noise of the dominant histogram mode.

    The mode is the peak of a 256-bin histogram (1-99.9 % range, smoothed over 2 bins); the
    noise is the root-mean-square distance from it of the values below it (the side without
    particles, so the particles' own tail does not widen it).

    Parameters
    ----------
    vals : ndarray of float

    Returns
    -------
    mode, sigma : float
    """
    lo, hi = np.quantile(vals, [0.001, 0.999])
    if hi <= lo:
        return float(lo), 0.0
    h, e = np.histogram(vals, 256, (lo, hi))
    centres = 0.5 * (e[:-1] + e[1:])
    mode = float(centres[int(np.argmax(ndi.gaussian_filter1d(h.astype(float), 2.0)))])
    below = vals[vals <= mode]
    sigma = float(np.sqrt(np.mean((below - mode) ** 2))) if below.size >= 50 else float(np.std(vals))
    return mode, sigma


def threshold_level(vals: np.ndarray, method="auto") -> tuple[float, str]:
    """Global threshold on the smoothed, flattened values, and how it was found.

    Parameters
    ----------
    vals : ndarray of float
    method : {"auto", "minimum", "otsu", "li", "triangle"} or float
        ``"auto"``: the valley between the two histogram modes
        (``skimage.filters.threshold_minimum``) when each side holds at least
        ``VALLEY_MIN_SHARE`` of the values, else the background mode + ``NOISE_K`` x its
        noise (:func:`background_mode`). ``"minimum"`` is the valley with Otsu as fallback.

    Returns
    -------
    level : float
    how : str
        ``"valley"``, ``"noise"``, the method name, or ``"user"``.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> vals = np.r_[rng.normal(0.2, 0.05, 9000), rng.normal(0.6, 0.05, 1000)]
    >>> t, how = threshold_level(vals)
    >>> 0.3 < t < 0.5, how
    (True, 'valley')
    >>> t, how = threshold_level(np.r_[rng.normal(0.2, 0.05, 9990), rng.normal(0.6, 0.05, 10)])
    >>> 0.3 < t < 0.45, how        # ten bright pixels are no class: mode + 3 sigma
    (True, 'noise')
    """
    if not isinstance(method, str):
        return float(method), "user"
    if method == "auto":
        try:
            t = float(filters.threshold_minimum(vals))
            share = float(np.mean(vals > t))
            if VALLEY_MIN_SHARE <= share <= 1.0 - VALLEY_MIN_SHARE:
                return t, "valley"
        except RuntimeError:
            pass
        mode, sigma = background_mode(vals)
        return mode + NOISE_K * sigma, "noise"
    if method == "otsu":
        return float(filters.threshold_otsu(vals)), method
    if method == "li":
        return float(filters.threshold_li(vals)), method
    if method == "triangle":
        return float(filters.threshold_triangle(vals)), method
    if method == "minimum":
        try:  # the valley between the two histogram modes; Otsu if there is no second mode
            return float(filters.threshold_minimum(vals)), method
        except RuntimeError:
            return float(filters.threshold_otsu(vals)), "otsu"
    raise ValueError(f"unknown threshold method {method!r}; expected a number or one of {THRESHOLDS}")


def _threshold(vals: np.ndarray, method) -> float:
    return threshold_level(vals, method)[0]


def cut_dark_lines(sm: np.ndarray, fg: np.ndarray, valid: np.ndarray, cut_px: float, cut_contrast: float) -> np.ndarray:
    """Foreground minus thin dark lines (the shadows between overlapping particles).

    A foreground pixel is cut when it is darker than its Gaussian (``cut_px``) neighbourhood
    mean by more than ``cut_contrast`` x (median foreground - median background level).
    Holes are filled again, so only lines open to the outside, i.e. the gaps between
    particles, survive.

    Returns
    -------
    ndarray of bool
    """
    contrast = float(np.median(sm[fg]) - np.median(sm[~fg & valid]))
    core = fg & (sm > ndi.gaussian_filter(sm, cut_px) - cut_contrast * contrast)
    return ndi.binary_fill_holes(core)


def expand_labels_into(lab: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Grow labels over the whole foreground: each foreground pixel takes its nearest label.

    Foreground components without any label become labels of their own. (Labels cover
    their components except thin cut lines, so the nearest label is the component's own.)
    """
    comps, _ = ndi.label(fg)
    seeded = np.unique(comps[lab > 0])
    markers = lab.copy()
    orphan = np.isin(comps, seeded, invert=True) & fg
    markers[orphan] = comps[orphan] + int(lab.max())
    if not markers.any():
        return markers
    _, (iy, ix) = ndi.distance_transform_edt(markers == 0, return_indices=True)
    return np.where(fg, markers[iy, ix], 0)


def refine_local(sm: np.ndarray, lab: np.ndarray, fg: np.ndarray, valid: np.ndarray, ring_px: int = REFINE_RING_PX) -> np.ndarray:
    """Move each particle's boundary to the midpoint of its own local contrast.

    A global threshold sits at one level for all particles; for small, faint or blurred
    particles it is far from the 50 % point of their edge (size bias). Per label: the
    background level B is the median of the non-foreground pixels 3 to ``2 + ring_px`` px
    away from it (the blurred edge itself excluded),
    the particle level F the median of its interior (eroded by 2 px; the maximum for tiny
    particles), and the region becomes the connected part of ``sm > (F + B) / 2`` within
    2 px of the old region, not taking pixels of other labels.

    Parameters
    ----------
    sm : ndarray of float
        Smoothed, flattened image.
    lab : ndarray of int
        Labels to refine.
    fg, valid : ndarray of bool
        Global foreground and valid pixels.
    ring_px : int, optional

    Returns
    -------
    ndarray of int
    """
    out = lab.copy()
    pad = ring_px + 5
    h, w = lab.shape
    ring_fp = morphology.disk(ring_px)
    grow_fp = morphology.disk(2)
    for i, obj in enumerate(ndi.find_objects(lab), start=1):
        if obj is None:
            continue
        y0, y1 = max(obj[0].start - pad, 0), min(obj[0].stop + pad, h)
        x0, x1 = max(obj[1].start - pad, 0), min(obj[1].stop + pad, w)
        win = (slice(y0, y1), slice(x0, x1))
        own = lab[win] == i
        near = ndi.binary_dilation(own, grow_fp)
        ring = ndi.binary_dilation(near, ring_fp) & ~near & ~fg[win] & valid[win]
        if ring.sum() < 8:
            continue  # no background nearby (dense cluster): keep the global boundary
        s_win = sm[win]
        core = ndi.binary_erosion(own, iterations=2)
        level_f = float(np.median(s_win[core])) if core.sum() >= 9 else float(s_win[own].max())
        level_b = float(np.median(s_win[ring]))
        if level_f <= level_b:
            continue
        cand = near & ((lab[win] == 0) | own) & valid[win]
        new = cand & (s_win > 0.5 * (level_f + level_b))
        comps, n = ndi.label(new)
        if n == 0:
            continue
        if n > 1:
            keep = np.bincount(comps[own], minlength=n + 1)
            keep[0] = 0
            new = comps == int(np.argmax(keep))
        new = ndi.binary_fill_holes(new)
        o = out[win]
        o[own & ~new] = 0
        o[new & ((o == 0) | own)] = i
    return out


def split_touching(fg: np.ndarray, neck_ratio: float = NECK_RATIO) -> np.ndarray:
    """Label a foreground mask, separating touching particles at narrow necks.

    Watershed of the negated distance transform from all its local maxima; then adjacent
    regions are merged, widest neck first, while the saddle of the distance transform on
    their common boundary is >= ``neck_ratio`` x the smaller of the two regions' peaks.

    Parameters
    ----------
    fg : ndarray of bool
    neck_ratio : float, optional
        ``inf`` keeps every watershed basin (maximal splitting); 0 merges every touching
        pair back (no splitting).

    Returns
    -------
    ndarray of int
        Labels (0 = background), not necessarily sequential.
    """
    dist = ndi.distance_transform_edt(fg)
    comps, _ = ndi.label(fg)
    peaks = peak_local_max(ndi.gaussian_filter(dist, 0.5), min_distance=1, labels=comps, exclude_border=False)
    markers = np.zeros(fg.shape, dtype=np.int64)
    markers[tuple(peaks.T)] = np.arange(1, len(peaks) + 1)
    # components without a peak (tiny) get one marker at their max
    missing = np.setdiff1d(np.unique(comps[comps > 0]), np.unique(comps[markers > 0]))
    if missing.size:
        pos = ndi.maximum_position(dist, comps, missing)
        for j, (y, x) in enumerate(pos):
            markers[y, x] = len(peaks) + 1 + j
    lab = segmentation.watershed(-dist, markers, mask=fg)
    return _merge_wide_necks(lab, dist, neck_ratio)


def _merge_wide_necks(lab: np.ndarray, dist: np.ndarray, neck_ratio: float) -> np.ndarray:
    nlab = int(lab.max())
    if nlab < 2:
        return lab
    peak = np.zeros(nlab + 1)
    np.maximum.at(peak, lab.ravel(), dist.ravel())
    # saddle per adjacent pair: max over boundary pixel pairs of min(dist_p, dist_q)
    pa, pb, sv = [], [], []
    for sl_a, sl_b in (
        ((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
        ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
    ):
        a, b = lab[sl_a], lab[sl_b]
        m = (a != b) & (a > 0) & (b > 0)
        pa.append(np.minimum(a[m], b[m]))
        pb.append(np.maximum(a[m], b[m]))
        sv.append(np.minimum(dist[sl_a][m], dist[sl_b][m]))
    pa, pb, sv = np.concatenate(pa), np.concatenate(pb), np.concatenate(sv)
    if pa.size == 0:
        return lab
    key = pa.astype(np.int64) * (nlab + 1) + pb
    order = np.lexsort((sv, key))
    key, sv = key[order], sv[order]
    last = np.r_[key[1:] != key[:-1], True]
    saddles: dict[int, dict[int, float]] = {}
    for k, s in zip(key[last].tolist(), sv[last].tolist()):
        a, b = divmod(k, nlab + 1)
        saddles.setdefault(a, {})[b] = s
        saddles.setdefault(b, {})[a] = s
    parent = list(range(nlab + 1))
    pk = peak.tolist()

    def ratio(a, b):
        return saddles[a][b] / max(min(pk[a], pk[b]), 1e-9)

    heap = [(-ratio(a, b), a, b) for a in saddles for b in saddles[a] if a < b]
    heapq.heapify(heap)
    while heap:
        negr, a, b = heapq.heappop(heap)
        if parent[a] != a or parent[b] != b or b not in saddles.get(a, {}):
            continue
        r = ratio(a, b)
        if abs(r + negr) > 1e-12:  # stale entry
            heapq.heappush(heap, (-r, a, b))
            continue
        if r < neck_ratio:
            break
        # merge b into a
        parent[b] = a
        pk[a] = max(pk[a], pk[b])
        for c, s in saddles.pop(b).items():
            del saddles[c][b]
            if c == a:
                continue
            saddles[a][c] = max(saddles[a].get(c, 0.0), s)
            saddles[c][a] = saddles[a][c]
        for c in saddles[a]:
            heapq.heappush(heap, (-ratio(a, c), min(a, c), max(a, c)))
    root = np.array(parent)
    for i in range(nlab + 1):  # path compression (parents point to earlier roots)
        j = i
        while root[j] != j:
            j = root[j]
        root[i] = j
    return root[lab]


def drop_shared_holes(lab: np.ndarray, fg_raw: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Return to the background the filled holes that border two or more particles.

    Hole filling closes the gap enclosed by a ring of touching particles as well as the
    pores of one textured particle. After the split the difference shows: a pore borders
    one particle, an enclosed gap several.

    Parameters
    ----------
    lab : ndarray of int
        Labels after the split.
    fg_raw, fg : ndarray of bool
        Foreground before and after hole filling.

    Returns
    -------
    ndarray of int
    """
    holes = fg & ~fg_raw
    hl, nh = ndi.label(holes)
    if nh == 0:
        return lab
    near = ndi.grey_dilation(hl, size=3)
    m = ndi.binary_dilation(holes) & (lab > 0) & (near > 0)
    pairs = np.unique(np.stack([near[m], lab[m]]), axis=1)
    shared = np.bincount(pairs[0], minlength=nh + 1) >= 2
    shared[0] = False
    out = lab.copy()
    out[shared[hl] & holes] = 0
    return out


def _grouped_median(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values`` per label 1..n (NaN where a label has no pixel), by one sort."""
    m = labels > 0
    v, g = values[m], labels[m]
    if v.size:  # one sort on label + value scaled into [0, 0.5)
        lo, span = float(v.min()), float(np.ptp(v)) or 1.0
        order = np.argsort(g + 0.5 * (v - lo) / span)
        v, g = v[order], g[order]
    count = np.bincount(g, minlength=n + 1)[1:]
    start = np.r_[0, np.cumsum(count)[:-1]]
    out = np.full(n, np.nan)
    has = count > 0
    lo = start[has] + (count[has] - 1) // 2
    hi = start[has] + count[has] // 2
    out[has] = 0.5 * (v[lo] + v[hi])
    return out


def drop_faint(lab: np.ndarray, x: np.ndarray, fg: np.ndarray, valid: np.ndarray, z: float = CONTRAST_Z,
               ring=(2, 6)) -> tuple[np.ndarray, int]:
    """Drop particles that do not stand out from their background (texture, noise).

    A particle's contrast is the median of its pixels minus the median of its ring: the
    background pixels 3-6 px away whose nearest particle it is. It must exceed ``z`` times
    the robust standard deviation (1.4826 x MAD) of that ring, and ``z`` times the robust
    standard deviation of the whole background (pixels 4 px or more from the foreground).
    A particle with fewer than 10 ring pixels (inside a dense cluster) is compared with the
    whole background's median instead.

    Parameters
    ----------
    lab : ndarray of int
    x : ndarray of float
        Flattened image (particles bright).
    fg, valid : ndarray of bool
    z : float, optional
    ring : (int, int), optional
        Inner and outer distance of the ring (px).

    Returns
    -------
    labels : ndarray of int
    dropped : int
        Number of particles dropped.
    """
    bg = valid & ~ndi.binary_dilation(fg, iterations=3)
    sigma_bg, level_bg = 0.0, -np.inf
    if bg.sum() > 100:
        level_bg = float(np.median(x[bg]))
        sigma_bg = 1.4826 * float(np.median(np.abs(x[bg] - level_bg)))
    n = int(lab.max())
    if n == 0:
        return lab, 0
    # ring: background pixels 3-6 px from a particle, each given to its nearest particle
    dist, (iy, ix) = ndi.distance_transform_edt(lab == 0, return_indices=True)
    ring = (dist > ring[0]) & (dist <= ring[1]) & ~fg & valid
    owner = np.where(ring, lab[iy, ix], 0)
    n_ring = np.bincount(owner.ravel(), minlength=n + 1)[1:]
    level_b = _grouped_median(x, owner, n)
    level_f = _grouped_median(x, lab, n)
    dev = np.abs(x - np.r_[0.0, np.nan_to_num(level_b)][owner])
    spread = 1.4826 * _grouped_median(dev, owner, n)
    present = np.bincount(lab.ravel(), minlength=n + 1)[1:] > 0
    local = n_ring >= 10
    faint = present & np.where(local, level_f - level_b < z * np.maximum(np.nan_to_num(spread), sigma_bg),
                               level_f - level_bg < z * sigma_bg)
    out = np.where(np.r_[False, faint][lab], 0, lab)
    dropped = int(faint.sum())
    return out, dropped


def remove_edge_and_specks(lab: np.ndarray, valid: np.ndarray, min_area_px: int) -> np.ndarray:
    """Drop labels touching the image border or the invalid area, and those below ``min_area_px``.

    Returns
    -------
    ndarray of int
        Sequential labels 1..n.
    """
    edge = np.ones(lab.shape, dtype=bool)
    edge[1:-1, 1:-1] = False
    edge |= ndi.binary_dilation(~valid)
    drop = np.unique(lab[edge & (lab > 0)])
    areas = np.bincount(lab.ravel())
    small = np.nonzero(areas < min_area_px)[0]
    out = lab.copy()
    out[np.isin(lab, np.union1d(drop, small))] = 0
    return segmentation.relabel_sequential(out)[0]


# --- the whole path -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment`.

    Attributes
    ----------
    labels : ndarray of int
        Particle labels 1..n in the (cropped) image frame, 0 = background or dropped.
    foreground : ndarray of bool
        Thresholded, hole-filled mask before splitting and removal.
    threshold : float
        Global threshold on the flattened, smoothed image (particles bright).
    offset : (int, int)
        (row, column) of the cropped frame's origin in the input image.
    raw_labels : ndarray of int or None
        Labels before the border and speck removal (for the quality checks).
    valid : ndarray of bool or None
        Valid pixels of the cropped frame (crop, mask and annotations excluded).
    polarity : {"bright", "dark"}
        Particles brighter or darker than their surroundings.
    polarity_source : {"user", "edges", "evidence"}
        Given; from the edge vote; from the evidence of both readings (near-tie).
    polarity_vote : float or None
        :func:`bmctl.measure.polarity.polarity_vote` (share voting "bright"), when computed.
    threshold_method : str
        How the threshold was found (``"valley"``, ``"noise"``, a method name, ``"user"``).
    annotation_px : int
        Pixels masked as drawn annotations.
    smoothed : ndarray of float or None
        The flattened, smoothed image the threshold applies to (particles bright).
    faint_dropped : int
        Candidates dropped as not standing out from their background (:func:`drop_faint`).
    """

    labels: np.ndarray
    foreground: np.ndarray
    threshold: float
    offset: tuple[int, int]
    raw_labels: np.ndarray | None = None
    valid: np.ndarray | None = None
    polarity: str = "bright"
    polarity_source: str = "user"
    polarity_vote: float | None = None
    threshold_method: str = ""
    annotation_px: int = 0
    smoothed: np.ndarray | None = None
    faint_dropped: int = 0


def _one_polarity(img, valid, dark, *, flatten, background_px, smooth_px, neck_ratio, threshold, cut_px,
                  cut_contrast, refine, contrast_z, extremes, name):
    """Steps 3-7 of :func:`segment` for one polarity: (labels before removal, fg, thr, how, smoothed, dropped)."""
    x = 1.0 - img if dark else img
    if flatten:
        bg_px = background_px if background_px is not None else max(32.0, min(x.shape) / 4.0)
        x = flatten_background(x, valid, bg_px)
    use = valid & ~extremes
    use = use if use.sum() >= 100 else valid
    scales = [smooth_px * f for f in VALLEY_SCALES] if threshold == "auto" and smooth_px > 0 else [smooth_px]
    for k, sigma in enumerate(scales):  # the finest smoothing at which the histogram has a valley
        sm = ndi.gaussian_filter(x, sigma) if sigma > 0 else x
        vals = sm[use]
        if np.ptp(vals) <= 1e-12:
            raise InputError(f"{name}: image is uniform, nothing to segment")
        thr, how = threshold_level(vals, threshold)
        if how != "noise":
            break
    else:  # no valley at any scale: a few particles on a dominant background; finest scale
        sm = ndi.gaussian_filter(x, scales[0]) if scales[0] > 0 else x
        thr, how = threshold_level(sm[use], threshold)
    fg_raw = (sm > thr) & valid
    fg = ndi.binary_fill_holes(fg_raw)
    if cut_contrast and cut_contrast > 0 and fg.any() and (~fg & valid).any():
        core = cut_dark_lines(sm, fg, valid, cut_px, cut_contrast)
        lab = expand_labels_into(split_touching(core, neck_ratio), fg)
    else:
        lab = split_touching(fg, neck_ratio)
    lab = drop_shared_holes(lab, fg_raw, fg)
    if refine:
        lab = refine_local(sm, lab, fg, valid)
    dropped = 0
    if contrast_z and contrast_z > 0:
        lab, dropped = drop_faint(lab, x, fg, valid, contrast_z)
    return lab, fg, thr, how, sm, dropped


def _near_tie(img, valid, offset, min_area_px, kw):
    """Both readings of an image whose edge vote is a near-tie; the one with the better evidence.

    Ranked by the reliability verdict each reading earns on its own evidence
    (:func:`bmctl.measure.quality.verdict`, without its limit on few particles: that one
    judges the sample, not the reading), then by fewer particles (under an unclear
    polarity, the reading that claims less).
    """
    from .quality import VERDICTS, auto_min_area, evidence, verdict

    ranked = []
    for p in ("bright", "dark"):
        run = _one_polarity(img, valid, p == "dark", **kw)
        lab, fg, thr, how, sm, dropped = run
        used = auto_min_area(lab, valid, min_area_px)
        kept = remove_edge_and_specks(lab, valid, used)
        seg = Segmentation(kept, fg, thr, offset, lab, valid, p, "evidence", None, how, 0, sm, dropped)
        value, _ = verdict(evidence(seg, used), min_particles=0)
        ranked.append((VERDICTS.index(value), int(kept.max()), p, run))
    ranked.sort(key=lambda r: r[:2])
    return ranked[0][2], ranked[0][3]


def segment(
    image,
    *,
    min_area_px: int = MIN_AREA_PX,
    crop=None,
    mask=None,
    flatten: bool = True,
    background_px: float | None = None,
    smooth_px: float = SMOOTH_PX,
    neck_ratio: float = NECK_RATIO,
    polarity: str = "auto",
    dark_particles: bool | None = None,
    threshold=THRESHOLD,
    cut_px: float = CUT_PX,
    cut_contrast: float = CUT_CONTRAST,
    refine: bool = True,
    annotations: bool = True,
    contrast_z: float = CONTRAST_Z,
    name: str = "image",
    drawn=None,
) -> Segmentation:
    """Segment the particles of a grayscale micrograph.

    Parameters
    ----------
    image : ndarray or path-like
        Gray or colour image, or a path to one.
    min_area_px : int, optional
        Smaller blobs are dropped (specks, noise).
    crop : (y0, y1, x0, x1) or str, optional
        Window to keep (``-1`` ends: to the edge; a string as for :func:`parse_crop`).
    mask : ndarray of bool, optional
        Valid pixels (same shape as the image before cropping); particles touching the
        invalid area are dropped like those touching the border.
    flatten : bool, optional
        Subtract a smooth background (uneven illumination).
    background_px : float, optional
        Footprint of the background estimate; > the largest particle diameter. Default:
        a quarter of the smaller image side (at least 32 px).
    smooth_px : float, optional
        Gaussian sigma before thresholding.
    neck_ratio : float, optional
        Merge criterion of :func:`split_touching`.
    polarity : {"auto", "bright", "dark"}, optional
        Particles brighter or darker than their surroundings; ``"auto"`` decides per image
        (:mod:`bmctl.measure.polarity`).
    dark_particles : bool, optional
        Older spelling of ``polarity``: ``True`` = ``"dark"``, ``False`` = ``"bright"``.
    threshold : {"auto", "minimum", "otsu", "li", "triangle"} or float, optional
        Global threshold method on the flattened, smoothed image, or the level itself
        (:func:`threshold_level`).
    cut_px, cut_contrast : float, optional
        Dark-line cut (:func:`cut_dark_lines`); ``cut_contrast=0`` switches it off.
    refine : bool, optional
        Per-particle boundary refinement (:func:`refine_local`).
    annotations : bool, optional
        Mask drawn panel letters, scale bars and label boxes
        (:func:`bmctl.measure.annotations.find_annotations`).
    contrast_z : float, optional
        Significance of a particle against its background (:func:`drop_faint`); 0 keeps all.
    name : str, optional
        Name used in error messages.
    drawn : ndarray of bool, optional
        Pixels known to be drawn marks (same shape as the image before cropping; ``bmctl
        measure`` passes the scale bar it found): masked with the annotations when
        ``annotations`` is true, after the search for the others (which sees them, so the text
        beside a bar is found as such).

    Returns
    -------
    Segmentation

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.measure.render import render_micrograph
    >>> m = render_micrograph(np.random.default_rng(0), n=8, shape=(160, 160), s_px=(20, 24))
    >>> seg = segment(m.image)
    >>> int(seg.labels.max()) == len(m.truth), seg.polarity
    (True, 'bright')
    >>> int(segment(1.0 - m.image).labels.max()) == len(m.truth)
    True
    """
    if dark_particles is not None:
        polarity = "dark" if dark_particles else "bright"
    if polarity not in POLARITIES:
        raise InputError(f"{name}: polarity: expected one of {', '.join(POLARITIES)} (got {polarity!r})")
    if not isinstance(image, np.ndarray):
        name = str(image)
        image = load_image(image)
    img = as_gray_float(image, name)
    valid = np.ones(img.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if valid.shape != img.shape:
        raise InputError(f"{name}: mask shape {valid.shape} differs from image shape {img.shape}")
    drawn = np.zeros(img.shape, dtype=bool) if drawn is None else np.asarray(drawn, dtype=bool)
    if drawn.shape != img.shape:
        raise InputError(f"{name}: drawn-mark mask shape {drawn.shape} differs from image shape {img.shape}")
    offset = (0, 0)
    if crop is not None:
        crop = parse_crop(crop) if isinstance(crop, str) else crop
        sy, sx = crop_slices(crop, img.shape, name)
        img, valid, drawn, offset = img[sy, sx], valid[sy, sx], drawn[sy, sx], (sy.start, sx.start)
    if valid.sum() < 64:
        raise InputError(f"{name}: fewer than 64 valid pixels after crop/mask")
    n_ann = 0
    if annotations:
        ann = find_annotations(img, valid) | (drawn & valid)
        n_ann = int(ann.sum())
        if n_ann and (valid & ~ann).sum() >= 64:
            valid = valid & ~ann
    vals = img[valid]
    lo, hi = float(vals.min()), float(vals.max())
    tol = max(SATURATION * (hi - lo), 1.5 / 255)
    extremes = (img <= lo + tol) | (img >= hi - tol)
    kw = dict(flatten=flatten, background_px=background_px, smooth_px=smooth_px, neck_ratio=neck_ratio,
              threshold=threshold, cut_px=cut_px, cut_contrast=cut_contrast, refine=refine,
              contrast_z=contrast_z, extremes=extremes, name=name)
    vote, source = None, "user"
    if polarity == "auto":
        vote = polarity_vote(img, valid)
        if abs(vote - 0.5) >= AMBIGUOUS:
            polarity, source = ("bright" if vote > 0.5 else "dark"), "edges"
        else:
            polarity, source = _near_tie(img, valid, offset, int(min_area_px), kw), "evidence"
            lab, fg, thr, how, sm, dropped = polarity[1]
            polarity = polarity[0]
    if source != "evidence":
        lab, fg, thr, how, sm, dropped = _one_polarity(img, valid, polarity == "dark", **kw)
    kept = remove_edge_and_specks(lab, valid, int(min_area_px))
    return Segmentation(kept, fg, thr, offset, lab, valid, polarity, source, vote, how, n_ann, sm, dropped)


def measure_labels(labels: np.ndarray, um_per_px: float, method: str = DEFAULT_METHOD) -> ParticleTable:
    """Area (pixel count) and perimeter of each label, as a :class:`ParticleTable` in um.

    Row ``i`` is label ``i + 1`` (labels must be sequential, as :func:`segment` returns).

    Parameters
    ----------
    labels : ndarray of int
    um_per_px : float
        Pixel size in micrometres.
    method : str, optional
        Perimeter estimator (:func:`bmctl.measure.perimeter.perimeter`).

    Returns
    -------
    ParticleTable
    """
    props = measure.regionprops(labels)
    if not props:
        return ParticleTable.empty()
    area = np.array([p.area_filled for p in props], dtype=float)
    perim = np.array([perimeter(np.pad(p.image_filled, 1), method) for p in props])
    return ParticleTable.from_area_perimeter(area * um_per_px**2, perim * um_per_px)


def measure_image(image, um_per_px: float, *, min_area_px: int = MIN_AREA_PX, crop=None, **kwargs) -> ParticleTable:
    """Segment a micrograph and measure its particles (area, perimeter, s, r in um).

    Parameters
    ----------
    image : ndarray or path-like
        Gray/colour image or a path to one.
    um_per_px : float
        Pixel size in micrometres (> 0).
    min_area_px : int, optional
        Specks smaller than this are dropped.
    crop : (y0, y1, x0, x1) or str, optional
        Window to keep, e.g. ``"0:423,:"`` to cut off an info bar.
    **kwargs
        Passed to :func:`segment` (``mask``, ``flatten``, ``background_px``,
        ``smooth_px``, ``neck_ratio``, ``polarity``, ...).

    Returns
    -------
    ParticleTable

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.measure.render import render_micrograph
    >>> m = render_micrograph(np.random.default_rng(1), n=12, shape=(256, 256), s_px=(20, 30))
    >>> t = measure_image(m.image, um_per_px=0.5)
    >>> len(t) >= 10
    True
    """
    um_per_px = check_scale(um_per_px)
    seg = segment(image, min_area_px=min_area_px, crop=crop, **kwargs)
    return measure_labels(seg.labels, um_per_px)
