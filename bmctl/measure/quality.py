"""Checks that flag a segmentation whose numbers are likely wrong, and the automatic speck limit.

Each check returns a warning (a short code and one line for the user) when its measured
quantity crosses a limit; ``docs/measurement.md`` §8.2 gives the limits and why.

* ``unsegmented``: share of the foreground (thresholded) area that ends in no kept particle
  (dropped at the border, as specks, or lost in the refinement) > ``LOST_SHARE``;
* ``merged``: share of the kept particle area in non-convex particles (solidity
  < ``MERGED_SOLIDITY``; touching particles segmented as one blob) > ``MERGED_SHARE``;
* ``border``: share of particles (above the speck limit) cut by the image border or the
  excluded area > ``BORDER_SHARE``;
* ``small``: share of kept particles below ``R_RELIABLE_PX`` px across (r is biased low by
  ~1/3 of its value there, docs/measurement.md §5.2) > ``SMALL_SHARE``;
* ``min-area``: the median size moves by more than ``MIN_AREA_JUMP`` when the speck limit is
  halved or doubled (the size distribution reaches down to the detection limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi
from skimage import measure

from .segment import MIN_AREA_PX, remove_edge_and_specks

AUTO_AREA_FRACTION = 0.01  # specks: < 1/100 of the area-weighted median area (1/10 of its diameter)
LOST_SHARE = 0.4
MERGED_SOLIDITY = 0.8
MERGED_SHARE = 0.3
BORDER_SHARE = 0.25
R_RELIABLE_PX = 10.0
SMALL_SHARE = 0.25
MIN_AREA_JUMP = 0.15


@dataclass(frozen=True)
class QualityWarning:
    """One warning: a short code, the measured value, its limit, and a line for the user."""

    code: str
    value: float
    limit: float
    message: str

    def as_dict(self) -> dict:
        """JSON-ready dict."""
        return {"code": self.code, "value": round(float(self.value), 4), "limit": self.limit, "message": self.message}


def _areas(labels: np.ndarray) -> np.ndarray:
    return np.bincount(labels.ravel())[1:].astype(float)


def auto_min_area(raw_labels: np.ndarray, valid: np.ndarray, floor: int = MIN_AREA_PX) -> int:
    """Speck limit scaled to the particles: ``max(floor, AUTO_AREA_FRACTION x area-weighted median area)``.

    The area-weighted median is carried by the particles that hold most of the area, so a
    swarm of specks does not pull it down. On the AMPIS powder it gives 124 px (hand-outline
    median size kept: 59 px against 60 by hand; 30 px gives 33), on the SiO2 image and the
    synthetic validation images the floor of 30 px.

    Parameters
    ----------
    raw_labels : ndarray of int
        Labels before border/speck removal (:attr:`Segmentation.raw_labels`).
    valid : ndarray of bool
    floor : int, optional

    Returns
    -------
    int
    """
    lab = remove_edge_and_specks(raw_labels, valid, 1)
    a = np.sort(_areas(lab))
    a = a[a > 0]
    if a.size == 0:
        return int(floor)
    c = np.cumsum(a)
    weighted_median = a[np.searchsorted(c, 0.5 * c[-1])]
    return int(max(floor, round(AUTO_AREA_FRACTION * weighted_median)))


def median_size_px(raw_labels: np.ndarray, valid: np.ndarray, min_area_px: int) -> float:
    """Median s (px, from the pixel count) of the particles kept at ``min_area_px``."""
    a = _areas(remove_edge_and_specks(raw_labels, valid, int(min_area_px)))
    a = a[a > 0]
    return float(np.median(2.0 * np.sqrt(a / np.pi))) if a.size else float("nan")


def check_segmentation(labels, raw_labels, foreground, valid, min_area_px: int) -> list[QualityWarning]:
    """Run all checks on one segmented image.

    Parameters
    ----------
    labels : ndarray of int
        Kept particles 1..n.
    raw_labels : ndarray of int
        Labels before border/speck removal.
    foreground : ndarray of bool
        Thresholded mask.
    valid : ndarray of bool
    min_area_px : int
        Speck limit used.

    Returns
    -------
    list of QualityWarning
    """
    out = []
    kept = labels > 0
    fg = foreground & valid
    n = int(labels.max())
    if fg.sum():
        lost = float((fg & ~kept).sum() / fg.sum())
        if lost > LOST_SHARE:
            out.append(QualityWarning("unsegmented", lost, LOST_SHARE,
                                      f"{lost:.0%} of the foreground area is in no measured particle (cut by the border, specks, or lost)"))
    if n:
        props = measure.regionprops(labels)
        area = np.array([p.area for p in props], float)
        solidity = np.array([p.solidity for p in props], float)
        merged = float(area[solidity < MERGED_SOLIDITY].sum() / area.sum())
        if merged > MERGED_SHARE:
            out.append(QualityWarning("merged", merged, MERGED_SHARE,
                                      f"{merged:.0%} of the particle area is in non-convex blobs (solidity < {MERGED_SOLIDITY}): touching particles likely merged"))
        d_px = 2.0 * np.sqrt(area / np.pi)
        small = float(np.mean(d_px < R_RELIABLE_PX))
        if small > SMALL_SHARE:
            out.append(QualityWarning("small", small, SMALL_SHARE,
                                      f"{small:.0%} of the particles are below {R_RELIABLE_PX:g} px across, where r is biased low; use a higher magnification or --min-area-px 80"))
    raw_a = _areas(raw_labels)
    big = set(np.nonzero(raw_a >= min_area_px)[0] + 1)
    edge = np.ones(raw_labels.shape, dtype=bool)
    edge[1:-1, 1:-1] = False
    edge |= ndi.binary_dilation(~valid)
    cut = set(np.unique(raw_labels[edge & (raw_labels > 0)]).tolist()) & big
    if big:
        border = len(cut) / len(big)
        if border > BORDER_SHARE:
            out.append(QualityWarning("border", border, BORDER_SHARE,
                                      f"{border:.0%} of the particles are cut by the image border or the excluded area (large particles are under-counted)"))
    jump, (lo, med, hi) = min_area_jump(raw_labels, valid, min_area_px)
    if jump > MIN_AREA_JUMP:
        px = " / ".join(f"{v:.1f}" if np.isfinite(v) else "none" for v in (lo, med, hi))
        out.append(QualityWarning("min-area", jump, MIN_AREA_JUMP,
                                  f"median size moves by {jump:.0%} when --min-area-px {min_area_px} is halved or doubled "
                                  f"({px} px): the size distribution reaches the detection limit"))
    return out


def min_area_jump(labels: np.ndarray, valid: np.ndarray, min_area_px: int) -> tuple[float, tuple[float, float, float]]:
    """How far the median particle size moves when the speck limit is halved or doubled (relative;
    1.0 where either leaves no particle), with the three medians (px; NaN: no particle). 0 where
    the image has no particle at the limit itself."""
    med = median_size_px(labels, valid, min_area_px)
    lo = median_size_px(labels, valid, max(1, min_area_px // 2))
    hi = median_size_px(labels, valid, 2 * min_area_px)
    if not np.isfinite(med):
        return 0.0, (lo, med, hi)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return 1.0, (lo, med, hi)
    return float(max(abs(lo / med - 1.0), abs(hi / med - 1.0))), (lo, med, hi)


# --- evidence for the reliability verdict ---------------------------------------------------------

THRESHOLD_STEP = 0.1  # threshold moved by +-10 % of the particle-background contrast


def _components_count(fg: np.ndarray, valid: np.ndarray, min_area_px: int) -> int:
    lab, n = ndi.label(fg & valid)
    if n == 0:
        return 0
    edge = np.ones(fg.shape, dtype=bool)
    edge[1:-1, 1:-1] = False
    edge |= ndi.binary_dilation(~valid)
    area = np.bincount(lab.ravel(), minlength=n + 1)
    ok = area >= min_area_px
    ok[np.unique(lab[edge])] = False
    ok[0] = False
    return int(ok.sum())


def threshold_stability(smoothed: np.ndarray, threshold: float, foreground: np.ndarray, valid: np.ndarray,
                        min_area_px: int) -> tuple[float, float]:
    """How much the foreground and the blob count move when the threshold moves by +-10 % of the contrast.

    Parameters
    ----------
    smoothed : ndarray of float
        Flattened, smoothed image (particles bright) the threshold applies to.
    threshold : float
    foreground : ndarray of bool
        Foreground at ``threshold`` (hole-filled).
    valid : ndarray of bool
    min_area_px : int

    Returns
    -------
    area_change : float
        Pixels that change side between the two shifted thresholds / foreground pixels.
    count_change : float
        Largest relative change of the number of interior blobs (>= ``min_area_px``).
    """
    fg = foreground & valid
    bg = ~foreground & valid
    if not fg.any() or not bg.any():
        return 1.0, 1.0
    step = THRESHOLD_STEP * float(np.median(smoothed[fg]) - np.median(smoothed[bg]))
    lo = ndi.binary_fill_holes((smoothed > threshold - step) & valid)
    hi = ndi.binary_fill_holes((smoothed > threshold + step) & valid)
    area_change = float((lo ^ hi).sum() / fg.sum())
    n0 = _components_count(foreground, valid, min_area_px)
    nl, nh = _components_count(lo, valid, min_area_px), _components_count(hi, valid, min_area_px)
    count_change = max(abs(nl - n0), abs(nh - n0)) / max(n0, 1)
    return area_change, float(count_change)


def evidence(seg, min_area_px: int) -> dict:
    """The measurement's own evidence on one segmented image (all scale-free shares and ratios).

    Parameters
    ----------
    seg : bmctl.measure.segment.Segmentation
        With ``labels`` after the speck limit ``min_area_px``.
    min_area_px : int

    Returns
    -------
    dict
        ``count``, ``unsegmented``, ``border``, ``merged``, ``small``, ``min_area_jump``,
        ``polarity_margin`` (None when the polarity was given), ``faint_share``,
        ``threshold_area_change``, ``threshold_count_change``, ``at_limit``.
    """
    labels, raw, fg, valid = seg.labels, seg.raw_labels, seg.foreground, seg.valid
    n = int(labels.max())
    kept = labels > 0
    fgv = fg & valid
    out = {"count": n}
    out["unsegmented"] = float((fgv & ~kept).sum() / fgv.sum()) if fgv.any() else 1.0
    area = np.bincount(labels.ravel())[1:].astype(float)
    if n:
        props = measure.regionprops(labels)
        solidity = np.array([p.solidity for p in props], float)
        out["merged"] = float(area[solidity < MERGED_SOLIDITY].sum() / area.sum())
        out["small"] = float(np.mean(2.0 * np.sqrt(area / np.pi) < R_RELIABLE_PX))
        out["at_limit"] = float(np.mean(area < 2 * min_area_px))
    else:
        out["merged"] = out["small"] = out["at_limit"] = 0.0
    raw_a = _areas(raw)
    big = set(np.nonzero(raw_a >= min_area_px)[0] + 1)
    edge = np.ones(raw.shape, dtype=bool)
    edge[1:-1, 1:-1] = False
    edge |= ndi.binary_dilation(~valid)
    cut = set(np.unique(raw[edge & (raw > 0)]).tolist()) & big
    out["border"] = len(cut) / len(big) if big else 0.0
    out["min_area_jump"], _ = min_area_jump(raw, valid, min_area_px)
    out["polarity_margin"] = None if seg.polarity_vote is None else float(abs(seg.polarity_vote - 0.5))
    out["faint_share"] = float(seg.faint_dropped / max(seg.faint_dropped + len(big), 1))
    if seg.smoothed is not None:
        a, c = threshold_stability(seg.smoothed, seg.threshold, fg, valid, min_area_px)
    else:
        a = c = float("nan")
    out["threshold_area_change"] = a
    out["threshold_count_change"] = c
    return out


# --- the verdict ------------------------------------------------------------------------------------

#: doubtful when any of these crosses its limit (docs/measurement.md, "Reliability verdict")
VERDICT_LIMITS = {
    "polarity_margin": 0.05,  # below: the edges do not tell bright from dark particles
    "merged": 0.2,  # above: a fifth of the particle area in non-convex blobs (merged particles)
    "at_limit": 0.3,  # above: the size law piles up at the speck limit (noise, texture, fragments)
    "min_area_jump": 0.5,  # above: the median size moves by half when the speck limit is halved or doubled
    "unsegmented": 0.5,  # above: half the foreground is in no measured particle
}
UNUSABLE_UNSEGMENTED = 0.8  # above: the measured particles are a small part of what the image shows
#: doubtful below this many particles: with n particles the sample's range holds the median with
#: probability 1 - 2 x 0.5^n, 0.875 for 4 and 0.94 for 5; fewer do not bracket it at 90 %
MIN_PARTICLES = 5
VERDICTS = ("ok", "doubtful", "unusable")


def verdict(ev: dict, min_particles: int = MIN_PARTICLES) -> tuple[str, list[str]]:
    """Reliability verdict of one image from its evidence (:func:`evidence`).

    ``unusable``: no particle, more than ``UNUSABLE_UNSEGMENTED`` of the foreground
    unmeasured, or two or more of the ``VERDICT_LIMITS`` crossed; ``doubtful``: one crossed,
    or fewer than ``min_particles`` particles (the segmentation may be right, but the image
    says little about the size law; this reason alone never makes an image ``unusable``);
    else ``ok``.

    Parameters
    ----------
    ev : dict
    min_particles : int, optional
        Fewer particles make an ``ok`` image ``doubtful`` (0 or 1: no such limit).

    Returns
    -------
    value : {"ok", "doubtful", "unusable"}
    reasons : list of str
        One short phrase per crossed limit.

    Examples
    --------
    >>> verdict({"count": 40, "polarity_margin": 0.3, "merged": 0.0, "at_limit": 0.1,
    ...          "min_area_jump": 0.02, "unsegmented": 0.1})
    ('ok', [])
    >>> verdict({"count": 40, "polarity_margin": 0.01, "merged": 0.0, "at_limit": 0.1,
    ...          "min_area_jump": 0.02, "unsegmented": 0.1})[0]
    'doubtful'
    >>> verdict({"count": 0, "polarity_margin": None, "merged": 0.0, "at_limit": 0.0,
    ...          "min_area_jump": 0.0, "unsegmented": 1.0})
    ('unusable', ['no particle found'])
    >>> verdict({"count": 2, "polarity_margin": 0.3, "merged": 0.0, "at_limit": 0.1,
    ...          "min_area_jump": 0.02, "unsegmented": 0.1})
    ('doubtful', ['few particles: 2 found (fewer than 5); statistics unreliable'])
    """
    if ev.get("count", 0) == 0:
        return "unusable", ["no particle found"]
    reasons = []
    m = ev.get("polarity_margin")
    if m is not None and m < VERDICT_LIMITS["polarity_margin"]:
        reasons.append(f"polarity unclear (edge vote {0.5 + m:.2f} : {0.5 - m:.2f})")
    if ev.get("merged", 0.0) > VERDICT_LIMITS["merged"]:
        reasons.append(f"{ev['merged']:.0%} of the particle area in merged (non-convex) blobs")
    if ev.get("at_limit", 0.0) > VERDICT_LIMITS["at_limit"]:
        reasons.append(f"{ev['at_limit']:.0%} of the particles within twice the speck limit (noise or fragments)")
    if ev.get("min_area_jump", 0.0) > VERDICT_LIMITS["min_area_jump"]:
        reasons.append(f"median size moves {ev['min_area_jump']:.0%} when the speck limit is halved or doubled")
    unseg = ev.get("unsegmented", 0.0)
    if unseg > VERDICT_LIMITS["unsegmented"]:
        reasons.append(f"{unseg:.0%} of the foreground in no measured particle")
    value = "unusable" if unseg > UNUSABLE_UNSEGMENTED or len(reasons) >= 2 else "doubtful" if reasons else "ok"
    n = int(ev.get("count", 0))
    if n < min_particles:  # a statistical doubt on top of the segmentation's: never raises it to unusable
        reasons.append(f"few particles: {n} found (fewer than {min_particles}); statistics unreliable")
        value = "doubtful" if value == "ok" else value
    return value, reasons
