"""One micrograph end to end: data bar, scale, segmentation, speck limit, table, centroids, checks.

:func:`measure_micrograph` is what ``bmctl measure`` runs per image; it returns everything
the command writes (table, overlay, ``measure.json`` entry) so that the user can see how each
number was obtained.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError
from ..naming import arg
from .loading import as_gray_float, load_image, parse_crop
from .quality import MIN_PARTICLES, QualityWarning, auto_min_area, check_segmentation, evidence, verdict
from .scale import Scale, ScaleBar, check_scale, find_info_bar, nearest_125, resolve_scale
from .segment import MIN_AREA_PX, Segmentation, measure_labels, remove_edge_and_specks, segment
from .tables import ParticleTable

SCALE_BAR_MISMATCH = 0.05  # metadata scale vs the 1-2-5 length nearest to the implied bar length
BAR_MARGIN_PX = 2  # the scale bar found is excluded with this margin (as the drawn annotations)


@dataclass(frozen=True)
class MicrographResult:
    """Everything measured on one image.

    Attributes
    ----------
    name : str
    image : ndarray
        The full input image (gray, [0, 1]).
    segmentation : Segmentation
    scale : Scale
    scale_bar : ScaleBar or None
    info_bar_row : int or None
        First excluded row of the data bar at the bottom (``None``: none found or kept).
    min_area_px : int
        Speck limit used.
    table : ParticleTable
    x_um, y_um : ndarray
        Centroids from the image's top-left corner.
    warnings : list of QualityWarning
    evidence : dict
        The measurement's own evidence (:func:`bmctl.measure.quality.evidence`).
    verdict : {"ok", "doubtful", "unusable"}
        Reliability verdict (:func:`bmctl.measure.quality.verdict`).
    verdict_reasons : list of str
    info_bar_top_last_row : int or None
        Last excluded row of a data bar at the top of the image, rows 0 to it excluded
        (``None``: none found or kept).
    """

    name: str
    image: np.ndarray
    segmentation: Segmentation
    scale: Scale
    scale_bar: ScaleBar | None
    info_bar_row: int | None
    min_area_px: int
    table: ParticleTable
    x_um: np.ndarray
    y_um: np.ndarray
    warnings: list
    evidence: dict | None = None
    verdict: str = "ok"
    verdict_reasons: list = dataclasses.field(default_factory=list)
    info_bar_top_last_row: int | None = None

    def report(self) -> dict:
        """JSON-ready summary: scale and how it was found, exclusions, counts, medians, warnings."""
        summ = self.table.summary()
        bar = None
        if self.scale_bar is not None:
            bar = {"row": self.scale_bar.row, "x0": self.scale_bar.x0, "x1": self.scale_bar.x1,
                   "rows": [self.scale_bar.y0, self.scale_bar.y1],
                   "length_px": self.scale_bar.length_px,
                   "length_um_at_this_scale": round(self.scale_bar.length_px * self.scale.um_per_px, 4)}
        return {
            "image": self.name,
            "shape_px": list(self.image.shape),
            "scale": {"um_per_px": self.scale.um_per_px, "source": self.scale.source, "detail": self.scale.detail},
            "scale_bar": bar,
            "info_bar_first_row": self.info_bar_row,
            "info_bar_top_last_row": self.info_bar_top_last_row,
            "min_area_px": self.min_area_px,
            "count": summ["count"],
            "s_median_um": _finite_or_none(summ["s_median_um"]),  # no particles: no median (JSON has no NaN)
            "r_median": _finite_or_none(summ["r_median"]),
            "warnings": [w.as_dict() for w in self.warnings],
            "verdict": {"value": self.verdict, "reasons": list(self.verdict_reasons)},
            "polarity": {"value": self.segmentation.polarity, "source": self.segmentation.polarity_source,
                         "vote": None if self.segmentation.polarity_vote is None else round(self.segmentation.polarity_vote, 4)},
            "evidence": None if self.evidence is None else {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.evidence.items()},
        }


def _finite_or_none(value):
    """``value``, or ``None`` when it is a float that is not finite."""
    return None if isinstance(value, float) and not np.isfinite(value) else value


def _scale_bar_check(scale: Scale, bar: ScaleBar | None) -> QualityWarning | None:
    if bar is None or scale.source == "scale-bar":
        return None
    implied = bar.length_px * scale.um_per_px
    off = abs(implied / nearest_125(implied) - 1.0)
    if off <= SCALE_BAR_MISMATCH:
        return None
    return QualityWarning("scale", off, SCALE_BAR_MISMATCH,
                          f"the scale bar ({bar.length_px:g} px) is {implied:.3g} µm at {scale.um_per_px:.4g} µm/px, "
                          f"not a round length: check the scale ({scale.source})")


def _bar_pixels(shape, bar: ScaleBar) -> np.ndarray:
    """The scale bar's rectangle widened by ``BAR_MARGIN_PX`` (its anti-aliased edge)."""
    y0 = bar.row if bar.y0 is None else bar.y0
    y1 = bar.row if bar.y1 is None else bar.y1
    out = np.zeros(shape, dtype=bool)
    out[max(y0 - BAR_MARGIN_PX, 0):y1 + BAR_MARGIN_PX + 1, max(bar.x0 - BAR_MARGIN_PX, 0):bar.x1 + BAR_MARGIN_PX + 1] = True
    return out


def measure_micrograph(source, *, um_per_px=None, scale_bar_um=None, keep_info_bar: bool = False,
                       min_area_px="auto", crop=None, min_particles: int = MIN_PARTICLES,
                       **segment_kw) -> MicrographResult:
    """Measure one micrograph with the scale found from metadata or its scale bar.

    Parameters
    ----------
    source : path-like or ndarray
        Image file or gray/colour array (arrays have no metadata: give ``um_per_px`` or
        ``scale_bar_um``).
    um_per_px : float, optional
        Pixel size; overrides the metadata.
    scale_bar_um : float, optional
        Length of the scale bar drawn on the image (used when there is no metadata).
    keep_info_bar : bool, optional
        Do not detect and exclude the data bar (at the bottom, or a banner at the top).
    min_area_px : int or "auto", optional
        Speck limit; ``"auto"`` = :func:`bmctl.measure.quality.auto_min_area`.
    crop : str or tuple, optional
        Window to keep (``"Y0:Y1,X0:X1"``).
    min_particles : int, optional
        An image with fewer particles is at least ``doubtful``
        (:data:`bmctl.measure.quality.MIN_PARTICLES`; 0 switches the limit off).
    **segment_kw
        Passed to :func:`bmctl.measure.segment.segment`.

    Returns
    -------
    MicrographResult

    Raises
    ------
    bmctl.errors.InputError
        Unreadable image, no scale, bad crop, ``min_particles`` not a whole number >= 0.
    """
    if isinstance(source, np.ndarray):
        name, path, img = "image", None, as_gray_float(source)
    else:
        name, path = str(source), os.fspath(source)
        img = load_image(path)
    if um_per_px is not None:
        um_per_px = check_scale(um_per_px)
    if scale_bar_um is not None:
        scale_bar_um = check_scale(scale_bar_um, "scale_bar_um")
    if isinstance(min_particles, bool) or not isinstance(min_particles, (int, np.integer)) or min_particles < 0:
        raise InputError(f"{arg('min_particles')}: expected a whole number >= 0 (got {min_particles!r})")
    info_row = None if keep_info_bar else find_info_bar(img)
    banner = None if keep_info_bar else find_info_bar(img, side="top")
    scale, bar = resolve_scale(path, img, um_per_px=um_per_px, scale_bar_um=scale_bar_um, info_top=info_row,
                               info_banner=banner)
    mask = None
    if crop is not None:
        crop = parse_crop(crop) if isinstance(crop, str) else crop
        if (not isinstance(crop, (tuple, list)) or len(crop) != 4
                or any(isinstance(c, bool) or not isinstance(c, (int, np.integer)) for c in crop)):
            raise InputError(f"{arg('crop')}: expected (y0, y1, x0, x1) whole pixel numbers or 'Y0:Y1,X0:X1' "
                             f"(got {crop!r})")
        if info_row is not None or banner is not None:
            mask = np.ones(img.shape, dtype=bool)
            if info_row is not None:
                mask[info_row:] = False
            if banner is not None:
                mask[:banner + 1] = False
    elif info_row is not None or banner is not None:
        crop = (0 if banner is None else banner + 1, -1 if info_row is None else info_row, 0, -1)
    if bar is not None and "drawn" not in segment_kw:
        segment_kw["drawn"] = _bar_pixels(img.shape, bar)  # masked with the annotations (unless switched off)
    auto = isinstance(min_area_px, str)
    if auto and min_area_px != "auto":
        raise InputError(f"{arg('min_area_px')}: expected a number of px or 'auto' (got {min_area_px!r})")
    if not auto and (isinstance(min_area_px, bool) or not isinstance(min_area_px, (int, np.integer, float))
                     or not (math.isfinite(min_area_px) and min_area_px >= 1)):  # -5 was taken, NaN a ValueError
        raise InputError(f"{arg('min_area_px')}: expected a number of px >= 1 or 'auto' (got {min_area_px!r})")
    floor = MIN_AREA_PX if auto else int(min_area_px)
    seg = segment(img, min_area_px=floor, crop=crop, mask=mask, name=name, **segment_kw)
    used = floor
    if auto:
        used = auto_min_area(seg.raw_labels, seg.valid, floor)
        if used != floor:
            seg = dataclasses.replace(seg, labels=remove_edge_and_specks(seg.raw_labels, seg.valid, used))
    table = measure_labels(seg.labels, scale.um_per_px)
    n = int(seg.labels.max())
    if n:
        cy, cx = np.array(ndi.center_of_mass(seg.labels > 0, seg.labels, np.arange(1, n + 1))).reshape(-1, 2).T
        x_um, y_um = (cx + seg.offset[1]) * scale.um_per_px, (cy + seg.offset[0]) * scale.um_per_px
    else:
        x_um = y_um = np.empty(0)
    warns = check_segmentation(seg.labels, seg.raw_labels, seg.foreground, seg.valid, used)
    extra = _scale_bar_check(scale, bar)
    if extra is not None:
        warns.insert(0, extra)
    ev = evidence(seg, used)
    value, reasons = verdict(ev, min_particles)
    return MicrographResult(name, img, seg, scale, bar, info_row, used, table, x_um, y_um, warns, ev, value, reasons,
                            banner)


def table_reports(csv_path) -> list[dict]:
    """Per-image reports of a particle table written by ``bmctl measure``, from the
    ``measure.json`` beside it (empty when there is none or it belongs to another table).

    Parameters
    ----------
    csv_path : path-like

    Returns
    -------
    list of dict
        The ``inputs`` entries of images (with ``image`` and ``verdict``).
    """
    import json
    from pathlib import Path

    from ..io import read_input_bytes

    p = Path(csv_path)
    side = p.parent / "measure.json"
    if not side.is_file():
        return []
    try:
        doc = json.loads(read_input_bytes(side).decode("utf-8"))
    except (InputError, ValueError, RecursionError):
        return []
    if not isinstance(doc, dict) or Path(str(doc.get("table", ""))).name != p.name:
        return []
    inputs = doc.get("inputs")
    if not isinstance(inputs, list):  # a hand-edited file: no entries to check (as for one that is not JSON)
        return []
    return [r for r in inputs if isinstance(r, dict) and isinstance(r.get("verdict"), dict)]


def check_verdicts(reports, accept_unusable: bool = False, flag: str = "--accept-unusable") -> list[str]:
    """Refuse ``unusable`` images and list the ``doubtful`` ones.

    Parameters
    ----------
    reports : list of dict
        Per-input reports (:meth:`MicrographResult.report` or :func:`table_reports`).
    accept_unusable : bool, optional
        Warn instead of refusing.
    flag : str, optional
        The option named in the refusal.

    Returns
    -------
    list of str
        One warning line per doubtful (or accepted unusable) image.

    Raises
    ------
    bmctl.errors.InputError
        An ``unusable`` image and ``accept_unusable`` is false.

    Examples
    --------
    >>> check_verdicts([{"image": "a.png", "verdict": {"value": "doubtful", "reasons": ["polarity unclear"]}}])
    ['a.png: verdict doubtful (polarity unclear): check its overlay before trusting its particles']
    """
    from .names import path_text

    lines = []
    for rep in reports:
        v = rep.get("verdict") if isinstance(rep, dict) else None
        if not isinstance(v, dict):
            continue
        reasons = v.get("reasons")
        reasons = reasons if isinstance(reasons, list) else [] if reasons is None else [reasons]  # a hand-edited file
        value, why = v.get("value"), "; ".join(str(r) for r in reasons)
        name = path_text(str(rep.get("image", "image")))  # printable: bytes of a path that are not UTF-8 as escapes
        if value == "unusable" and not accept_unusable:
            raise InputError(f"{name}: verdict unusable ({why}); the measurement does not hold, "
                             f"check its overlay (bmctl measure) or pass {flag}")
        if value in ("doubtful", "unusable"):
            lines.append(f"{name}: verdict {value} ({why}): check its overlay before trusting its particles")
    return lines
