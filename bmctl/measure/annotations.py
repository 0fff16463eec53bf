"""Annotations drawn onto a micrograph: panel letters, scale bars, labels and their boxes.

Figures cut from papers carry panel letters ("(a)", "b2"), scale bars with their text
("200 nm") and the boxes behind them. They are drawn in the image's extreme values (pure
black or white), and they are not particles: counted, they add false particles; left in the
histogram, they pull a global threshold towards themselves (a white "(d)" takes the valley
between the white text and the rest, and the real particles are lost).

:func:`find_annotations` marks them from two properties that micrograph content rarely has
together: the pixels sit at one of the image's two extreme values, and the shape is either a
filled axis-aligned rectangle (a bar, a box, the glyph "1" or "l"), a bar with marks touching
it (its end ticks, a label joined to it by a tick), or a thin stroke (a glyph: its widest
inscribed disc is small against its extent and it is far from convex). Saturated components
lined up with an annotation and of a similar height (the rest of a word) are annotations too,
and so are glyph-shaped ones beside a bar even when their anti-aliased edges blur into the
background. A box drawn in an extreme value on a background close to it (a white label box on
a light micrograph) is told by what it holds: text and a bar in the other half of the range.
A saturated dark TEM particle is convex and thick, so it stays.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

SATURATION = 0.03  # within this share of the image's range of its min or max
MIN_AREA_PX = 12  # smaller saturated specks are not judged
RECT_EXTENT = 0.88  # filled area / bounding-box area of an axis-aligned rectangle
BAR_ASPECT = 3.0  # a bar is at least this long for its width (a box holds text instead)
GLYPH_SOLIDITY = 0.8  # glyphs are far from convex
GLYPH_STROKE = 0.2  # widest inscribed radius / longer bounding-box side of a glyph
GLYPH_HEIGHT = 0.15  # a glyph is at most this share of the image height
RING_CONTRAST = 0.3  # drawn marks differ from their surroundings by this share of the range
BOX_CONTENT_CONTRAST = 0.5  # the marks held by a box differ from it by this share of the range
BAR_MIN_PX = 20  # a bar with marks touching it is at least this long (as bmctl.measure.scale.SCALE_BAR_MIN_PX) ...
BAR_CORE_EXTENT = 0.95  # ... a filled rectangle with straight sides (saturated, so no anti-aliased rim) ...
BAR_CORE_SHARE = 0.5  # ... holding at least this share of its component (ticks and a joined label the rest)
CORNER = 0.25  # panel letters sit within this share of the width and height of a corner
MARGIN_PX = 2  # anti-aliased edge added around each annotation
MAX_SHARE = 0.1  # an annotation's bounding box covers at most this share of the image


def _components(mask: np.ndarray):
    lab, n = ndi.label(mask, structure=np.ones((3, 3), bool))
    return lab, n, ndi.find_objects(lab)


def _convex_area(sub: np.ndarray) -> float:
    from skimage.morphology import convex_hull_image

    return float(convex_hull_image(sub).sum())


def _bar_core(sub: np.ndarray) -> bool:
    """Whether a component is mostly a straight bar: what survives an opening by a line of
    ``BAR_MIN_PX`` px (end ticks, a label joined by a tick and glyph strokes do not) is a filled
    rectangle ``BAR_ASPECT`` x longer than thick with ``BAR_CORE_SHARE`` of the pixels."""
    for line in (np.ones((1, BAR_MIN_PX), bool), np.ones((BAR_MIN_PX, 1), bool)):
        if sub.shape[int(line.shape[1] > 1)] < BAR_MIN_PX:
            continue
        core = ndi.binary_opening(sub, structure=line)
        lab, n = ndi.label(core)
        if n == 0:
            continue
        sizes = np.bincount(lab.ravel())[1:]
        k = int(np.argmax(sizes))
        sl = ndi.find_objects(lab)[k]
        h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        if (min(h, w) >= 2 and max(h, w) >= BAR_ASPECT * min(h, w) and sizes[k] >= BAR_CORE_EXTENT * h * w
                and sizes[k] >= BAR_CORE_SHARE * sub.sum()):
            return True
    return False


def _classify(lab: np.ndarray, objs, img: np.ndarray, extreme: float, span: float):
    """Per component: kind (0 none, 1 bar or box, 2 glyph-like, 3 glyph-shaped but not set off
    from its surroundings) and bounding box (y0, y1, x0, x1)."""
    n = len(objs)
    kind = np.zeros(n + 1, np.int8)
    boxes = np.zeros((n + 1, 4), int)
    H, W = lab.shape
    for i, sl in enumerate(objs, start=1):
        if sl is None:
            continue
        boxes[i] = (sl[0].start, sl[0].stop, sl[1].start, sl[1].stop)
        h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        if h * w > MAX_SHARE * lab.size or max(h, w) < 4:
            continue
        sub = lab[sl] == i
        area = int(sub.sum())
        if area < MIN_AREA_PX:
            continue
        filled = ndi.binary_fill_holes(sub)
        shape_kind = 0
        if min(h, w) >= 2 and filled.sum() >= RECT_EXTENT * h * w:
            if max(h, w) >= BAR_ASPECT * min(h, w) or filled.sum() > 1.05 * area:
                shape_kind = 1  # bar, or a box holding text
        elif max(h, w) >= BAR_MIN_PX and _bar_core(sub):
            shape_kind = 1  # a bar with its ticks or a label touching it
        elif max(h, w) >= 6 and h <= GLYPH_HEIGHT * H:
            stroke = float(ndi.distance_transform_edt(np.pad(sub, 1)).max())
            if stroke <= GLYPH_STROKE * max(h, w) and area <= GLYPH_SOLIDITY * _convex_area(sub):
                shape_kind = 2
        if not shape_kind:
            continue
        y0, y1 = max(sl[0].start - 4, 0), min(sl[0].stop + 4, H)
        x0, x1 = max(sl[1].start - 4, 0), min(sl[1].stop + 4, W)
        own = lab[y0:y1, x0:x1] == i
        ring = ndi.binary_dilation(own, iterations=3) & ~own & (lab[y0:y1, x0:x1] == 0)
        if ring.sum() >= 4 and abs(float(np.median(img[y0:y1, x0:x1][ring])) - extreme) >= RING_CONTRAST * span:
            kind[i] = shape_kind  # set off from its surroundings: a drawn mark, not image content
        elif shape_kind == 1 and filled.sum() > 1.05 * area:
            held = img[sl][filled & ~sub]  # a box on a background close to it: judged by the marks it holds
            if abs(float(np.median(held)) - extreme) >= BOX_CONTENT_CONTRAST * span:
                kind[i] = 1
        elif shape_kind == 2:
            kind[i] = 3  # a glyph whose anti-aliased edge blurs into its surroundings: kept only beside a bar
    return kind, boxes


def _aligned(boxes: np.ndarray, i: int, others: np.ndarray) -> np.ndarray:
    """Which ``others`` stand on the same text line as ``i`` (a neighbouring letter)."""
    if others.size == 0:
        return np.zeros(0, bool)
    y0, y1, x0, x1 = boxes[i]
    a = boxes[others]
    hi_, ha = y1 - y0, (a[:, 1] - a[:, 0])
    overlap_y = np.minimum(a[:, 1], y1) - np.maximum(a[:, 0], y0)
    gap_x = np.maximum(a[:, 2], x0) - np.minimum(a[:, 3], x1)
    return (overlap_y >= 0.5 * np.minimum(ha, hi_)) & (gap_x <= np.maximum(ha, hi_)) & (ha <= 2 * hi_) & (hi_ <= 2 * ha)


def _near_bar(boxes: np.ndarray, i: int, bars: np.ndarray) -> bool:
    """A label written next to a scale bar (above, below or beside it, within two letter heights)."""
    if bars.size == 0:
        return False
    y0, y1, x0, x1 = boxes[i]
    h = y1 - y0
    a = boxes[bars]
    gap_y = np.maximum(a[:, 0], y0) - np.minimum(a[:, 1], y1)
    gap_x = np.maximum(a[:, 2], x0) - np.minimum(a[:, 3], x1)
    return bool(np.any((gap_y <= 2 * h) & (gap_x <= 2 * h)))


def _select(kind: np.ndarray, boxes: np.ndarray, shape) -> np.ndarray:
    """Annotations: bars and boxes; glyphs in a corner, on a line with another glyph, or by a bar;
    glyph shapes not set off from their surroundings only by a bar."""
    H, W = shape
    bars = np.nonzero(kind == 1)[0]
    glyphs = np.nonzero(kind == 2)[0]
    is_ann = kind == 1
    for i in np.nonzero(kind == 3)[0]:
        if _near_bar(boxes, i, bars):
            is_ann[i] = True
    for i in glyphs:
        y0, y1, x0, x1 = boxes[i]
        corner = (y1 <= CORNER * H or y0 >= (1 - CORNER) * H) and (x1 <= CORNER * W or x0 >= (1 - CORNER) * W)
        word = _aligned(boxes, i, glyphs[glyphs != i]).any()
        if corner or word or _near_bar(boxes, i, bars):
            is_ann[i] = True
    # the rest of each word: saturated components on a line with an annotation letter
    heights = boxes[:, 1] - boxes[:, 0]
    cand = np.nonzero((heights >= 4) & ~is_ann)[0]
    cand = cand[cand > 0]
    changed = True
    while changed and cand.size:
        changed = False
        ann = np.nonzero(is_ann & (kind != 1))[0]
        keep = []
        for c in cand:
            if _aligned(boxes, c, ann).any():
                is_ann[c] = True
                changed = True
            else:
                keep.append(c)
        cand = np.array(keep, int)
    # pieces of a bar's label that are no letter on their own (a stroke cut off by the anti-aliasing,
    # a decimal point): text-sized components centred in the box spanned by the bar and the marks beside it
    rest = np.nonzero(~is_ann & (heights >= 4) & (heights <= GLYPH_HEIGHT * H))[0]
    rest = rest[rest > 0]
    marks = np.nonzero(is_ann & (kind != 1))[0]
    for b in bars:
        if rest.size == 0:
            break
        near = [m for m in marks if _near_bar(boxes, m, np.array([b]))]
        blk = boxes[[b, *near]]
        cy, cx = 0.5 * (boxes[rest, 0] + boxes[rest, 1]), 0.5 * (boxes[rest, 2] + boxes[rest, 3])
        inside = (cy >= blk[:, 0].min()) & (cy < blk[:, 1].max()) & (cx >= blk[:, 2].min()) & (cx < blk[:, 3].max())
        is_ann[rest[inside]] = True
        rest = rest[~inside]
    is_ann[0] = False
    return is_ann


def find_annotations(img: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Pixels of drawn annotations (letters, scale bars, label boxes) in a gray image.

    Parameters
    ----------
    img : ndarray of float, shape (H, W)
        Gray image.
    valid : ndarray of bool, optional
        Pixels to look at (default all).

    Returns
    -------
    ndarray of bool
        Annotation pixels, each annotation widened by ``MARGIN_PX``; boxes include their
        content.

    Examples
    --------
    >>> import numpy as np
    >>> img = np.full((60, 80), 0.4)
    >>> img[50:54, 10:60] = 1.0                      # a scale bar
    >>> yy, xx = np.mgrid[:60, :80]
    >>> img[(yy - 20) ** 2 + (xx - 40) ** 2 < 100] = 1.0   # a saturated round particle
    >>> ann = find_annotations(img)
    >>> bool(ann[52, 30]), bool(ann[20, 40])
    (True, False)
    """
    valid = np.ones(img.shape, bool) if valid is None else valid
    v = img[valid]
    if v.size == 0:
        return np.zeros(img.shape, bool)
    lo, hi = float(v.min()), float(v.max())
    span = hi - lo
    out = np.zeros(img.shape, bool)
    if span <= 1e-6:
        return out
    tol = max(SATURATION * span, 1.5 / 255)
    for extreme, sat in ((hi, (img >= hi - tol) & valid), (lo, (img <= lo + tol) & valid)):
        lab, n, objs = _components(sat)
        if n == 0:
            continue
        kind, boxes = _classify(lab, objs, img, extreme, span)
        sel = _select(kind, boxes, img.shape)[lab]
        out |= ndi.binary_fill_holes(sel)  # a box holds its text
    if out.any():
        out = ndi.binary_dilation(out, iterations=MARGIN_PX)
    return out & valid
