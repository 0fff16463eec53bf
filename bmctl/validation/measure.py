"""Validation of the segmentation: matching to ground truth, synthetic sweeps, hand outlines.

Used by ``tests/measure/test_measure.py`` and ``benchmarks/measure_accuracy.py`` (which writes the
results files behind the tables of ``docs/measurement.md``). Quick printouts::

    python -m bmctl.validation.measure            # all tables (about two minutes)
    python -m bmctl.validation.measure bias       # perimeter-estimator bias only
    python -m bmctl.validation.measure sweep      # resolution sweep only
    python -m bmctl.validation.measure ampis [PATH_TO_PNG PATH_TO_JSON]
    python -m bmctl.validation.measure synthetic | sensitivity
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass

import numpy as np
from skimage import draw

from ..errors import InputError
from ..measure.render import render_micrograph
from ..measure.segment import measure_labels, segment
from ..measure.tables import ParticleTable


def match_labels(found: np.ndarray, ref: np.ndarray, min_iou: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one matches between two label images by intersection over union.

    With ``min_iou >= 0.5`` a region can overlap at most one other region that much, so
    the matches are unique without any assignment step.

    Parameters
    ----------
    found, ref : ndarray of int
        Label images of the same shape (0 = background).
    min_iou : float, optional

    Returns
    -------
    i_found, i_ref : ndarray of int
        Matched label ids.
    iou : ndarray of float
    """
    a, b = found.ravel(), ref.ravel()
    both = (a > 0) & (b > 0)
    if not both.any():
        return np.empty(0, int), np.empty(0, int), np.empty(0)
    pairs, cnt = np.unique(np.stack([a[both], b[both]]), axis=1, return_counts=True)
    na = np.bincount(a, minlength=int(a.max()) + 1)
    nb = np.bincount(b, minlength=int(b.max()) + 1)
    iou = cnt / (na[pairs[0]] + nb[pairs[1]] - cnt)
    k = iou > min_iou
    return pairs[0][k], pairs[1][k], iou[k]


@dataclass(frozen=True)
class Comparison:
    """Errors of matched particles: measured vs reference.

    Attributes
    ----------
    n_ref, n_found, n_matched : int
    s_rel_err : ndarray
        s_measured / s_reference - 1.
    r_err : ndarray
        r_measured - r_reference.
    r_ref : ndarray
        Reference r of the matched particles.
    """

    n_ref: int
    n_found: int
    n_matched: int
    s_rel_err: np.ndarray
    r_err: np.ndarray
    r_ref: np.ndarray

    @property
    def matched_fraction(self) -> float:
        """Share of reference particles matched."""
        return self.n_matched / max(self.n_ref, 1)

    @property
    def precision(self) -> float:
        """Share of found particles matched to a reference particle."""
        return self.n_matched / max(self.n_found, 1)

    def summary(self) -> dict[str, float]:
        """Medians of |s error|, s error, |r error|, r error; matched fraction, precision."""
        med = (lambda v: float(np.median(v)) if v.size else float("nan"))
        return {
            "matched": self.matched_fraction,
            "precision": self.precision,
            "s_mae": med(np.abs(self.s_rel_err)),
            "s_bias": med(self.s_rel_err),
            "r_mae": med(np.abs(self.r_err)),
            "r_bias": med(self.r_err),
            "r_ref_median": med(self.r_ref),
        }

    @staticmethod
    def concat(parts) -> "Comparison":
        """Pool several comparisons."""
        parts = list(parts)
        return Comparison(
            sum(p.n_ref for p in parts), sum(p.n_found for p in parts), sum(p.n_matched for p in parts),
            np.concatenate([p.s_rel_err for p in parts]), np.concatenate([p.r_err for p in parts]),
            np.concatenate([p.r_ref for p in parts]),
        )


def compare(found_labels, found: ParticleTable, ref_labels, ref: ParticleTable, ref_keep=None, min_iou: float = 0.5) -> Comparison:
    """Match found to reference particles (IoU) and collect the s and r errors.

    Row ``i`` of each table belongs to label ``i + 1``. ``ref_keep`` (bool per reference
    row) restricts the reference set, e.g. to particles not cut by the image border.
    """
    keep = np.ones(len(ref), bool) if ref_keep is None else np.asarray(ref_keep, bool)
    i_f, i_r, _ = match_labels(found_labels, ref_labels, min_iou)
    k = keep[i_r - 1]
    i_f, i_r = i_f[k], i_r[k]
    return Comparison(
        int(keep.sum()), len(found), len(i_f),
        found.s_um[i_f - 1] / ref.s_um[i_r - 1] - 1, found.r[i_f - 1] - ref.r[i_r - 1], ref.r[i_r - 1],
    )


# --- synthetic ------------------------------------------------------------------------------------

def synthetic_comparison(rng: np.random.Generator, n_images: int = 2, *, segment_kw=None, **render_kw) -> Comparison:
    """Render ``n_images`` micrographs, segment them, compare with the ground truth.

    Parameters
    ----------
    rng : numpy.random.Generator
    n_images : int, optional
    segment_kw : dict, optional
        Passed to :func:`bmctl.measure.segment.segment`.
    **render_kw
        Passed to :func:`bmctl.measure.render.render_micrograph`.

    Returns
    -------
    Comparison
    """
    parts = []
    for _ in range(n_images):
        m = render_micrograph(rng, **render_kw)
        seg = segment(m.image, **(segment_kw or {}))
        tab = measure_labels(seg.labels, m.um_per_px)
        parts.append(compare(seg.labels, tab, m.labels, m.truth))
    return Comparison.concat(parts)


def resolution_sweep(diameters_px=(5, 7, 10, 14, 20, 28, 40), seed: int = 0, shape=(384, 384), k_range=None, n_images: int = 2) -> list[dict]:
    """s and r errors against particle size in px (sizes within +-5 % of each value).

    About 150 particles per image (fewer for large sizes), ``n_images`` images per size,
    r ~ U(0, 0.2), ``min_area_px=8``
    so that the smallest are not dropped.

    Returns
    -------
    list of dict
        ``d_px`` and :meth:`Comparison.summary` per size.
    """
    rows = []
    for d in diameters_px:
        rng = np.random.default_rng([seed, int(d)])
        n = int(min(150, 60 * (40 / d) ** 1.5))
        kw = dict(n=n, shape=shape, s_px=(0.95 * d, 1.05 * d))
        if k_range is not None:
            kw["k_range"] = k_range
        c = synthetic_comparison(rng, n_images, segment_kw={"min_area_px": 8}, **kw)
        rows.append({"d_px": d, **c.summary()})
    return rows


# --- hand-drawn outlines (VGG Image Annotator) ---------------------------------------------------

def via_polygons(json_path: str | os.PathLike) -> list[tuple[np.ndarray, np.ndarray]]:
    """Polygons (x, y in px) of a VGG Image Annotator 2 project with one image.

    Raises
    ------
    bmctl.errors.InputError
        Not a VIA project, or no polygons.
    """
    p = str(json_path)
    try:
        meta = json.loads(open(p, encoding="utf-8").read())["_via_img_metadata"]
        regions = next(iter(meta.values()))["regions"]
    except (OSError, ValueError, KeyError, StopIteration) as exc:
        raise InputError(f"{p}: not a VGG Image Annotator project ({type(exc).__name__})") from None
    polys = [
        (np.asarray(r["shape_attributes"]["all_points_x"], float), np.asarray(r["shape_attributes"]["all_points_y"], float))
        for r in regions
        if r["shape_attributes"].get("name") == "polygon"
    ]
    if not polys:
        raise InputError(f"{p}: no polygon regions")
    return polys


def rasterise(polys, shape) -> tuple[np.ndarray, np.ndarray]:
    """Label image of polygons (later ones win overlaps) and whether each touches the border.

    Returns
    -------
    labels : ndarray of int
        Polygon ``i`` is label ``i + 1``.
    on_border : ndarray of bool
    """
    h, w = shape
    labels = np.zeros(shape, dtype=np.int32)
    border = np.zeros(len(polys), bool)
    for i, (x, y) in enumerate(polys):
        rr, cc = draw.polygon(y, x, shape)
        labels[rr, cc] = i + 1
        border[i] = rr.size == 0 or rr.min() <= 0 or cc.min() <= 0 or rr.max() >= h - 1 or cc.max() >= w - 1
    return labels, border


def polygon_lengths(polys) -> tuple[np.ndarray, np.ndarray]:
    """Area (shoelace) and perimeter of closed polygons, in px."""
    area, perim = [], []
    for x, y in polys:
        xn, yn = np.roll(x, -1), np.roll(y, -1)
        area.append(0.5 * abs(np.sum(x * yn - xn * y)))
        perim.append(float(np.hypot(xn - x, yn - y).sum()))
    return np.array(area), np.array(perim)


def hand_comparison(image_path, json_path, min_area_px: int = 30, **segment_kw) -> tuple[Comparison, dict]:
    """Segment a real micrograph and compare with hand-drawn outlines (areas from the raster).

    The reference set is the outlined particles that do not touch the image border (the
    segmentation drops those) with at least ``min_area_px`` px. Both sides are measured
    the same way (:func:`measure_labels` on the rasterised outlines), so the comparison is
    of the segmentation, not of the perimeter estimator.

    Returns
    -------
    Comparison
    extra : dict
        ``n_outlines``, ``seconds`` (segmentation time).
    """
    import time

    from ..measure.segment import load_image

    img = load_image(image_path)
    polys = via_polygons(json_path)
    ref_labels, border = rasterise(polys, img.shape)
    ref = measure_labels(ref_labels, 1.0)
    t0 = time.perf_counter()
    seg = segment(img, min_area_px=min_area_px, **segment_kw)
    dt = time.perf_counter() - t0
    found = measure_labels(seg.labels, 1.0)
    keep = ~border & (ref.area_um2 >= min_area_px)
    return compare(seg.labels, found, ref_labels, ref, keep), {"n_outlines": len(polys), "seconds": dt}


def sensitivity(image_path, json_path, seed: int = 7) -> list[dict]:
    """Matched fraction and errors when one segmentation parameter at a time moves off its default.

    Real image (hand outlines) and synthetic images (s = 10-40 px) side by side; the
    defaults were chosen on these same images, so this shows how sharp the choice is.
    """
    variants = [
        ("defaults", {}),
        ("threshold=otsu", {"threshold": "otsu"}),
        ("threshold=li", {"threshold": "li"}),
        ("cut_contrast=0 (no dark-line cut)", {"cut_contrast": 0.0}),
        ("cut_contrast=0.05", {"cut_contrast": 0.05}),
        ("cut_contrast=0.12", {"cut_contrast": 0.12}),
        ("neck_ratio=0.65", {"neck_ratio": 0.65}),
        ("neck_ratio=0.9", {"neck_ratio": 0.9}),
        ("smooth_px=1.0", {"smooth_px": 1.0}),
        ("refine=False", {"refine": False}),
    ]
    rows = []
    for name, kw in variants:
        real, _ = hand_comparison(image_path, json_path, **kw)
        syn = synthetic_comparison(np.random.default_rng(seed), 2, segment_kw=kw, n=60, shape=(384, 384), s_px=(10, 40))
        a, b = real.summary(), syn.summary()
        rows.append({
            "variant": name, "real matched": a["matched"], "real precision": a["precision"], "real s_mae": a["s_mae"],
            "real r_mae": a["r_mae"], "syn matched": b["matched"], "syn s_mae": b["s_mae"], "syn r_mae": b["r_mae"],
        })
    return rows


def _fmt(rows, cols) -> str:
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        out.append("| " + " | ".join(f"{r[c]:.3f}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    return "\n".join(out)


def main(argv=None) -> int:  # pragma: no cover - documentation helper
    argv = sys.argv[1:] if argv is None else argv
    what = argv[0] if argv else "all"
    if what in ("all", "bias"):
        from .perimeter import bias_study, format_table

        print("perimeter estimators on pixel masks of known shapes (40 placements per cell)")
        print(format_table(bias_study()) + "\n")
    if what in ("all", "sweep"):
        cols = ["d_px", "matched", "s_mae", "s_bias", "r_mae", "r_bias"]
        print("resolution sweep, lobes k = 3-5 (renderer default)")
        print(_fmt(resolution_sweep(), cols))
        print("\nresolution sweep, lobes k = 3-7 (finer boundary detail)")
        print(_fmt(resolution_sweep(k_range=(3, 7)), cols))
    if what in ("all", "synthetic"):
        for s_px in ((10, 14), (20, 40)):
            c = synthetic_comparison(np.random.default_rng(7), 2, n=60, shape=(384, 384), s_px=s_px)
            print(f"\nsynthetic s_px={s_px}:", {k: round(v, 4) for k, v in c.summary().items()})
    png = argv[1] if len(argv) > 2 else "tests/data/ampis_powder_b.png"
    js = argv[2] if len(argv) > 2 else "tests/data/ampis_masks_validation.json"
    if what in ("all", "ampis"):
        c, extra = hand_comparison(png, js)
        print("\nAMPIS powder vs hand outlines:", {k: round(v, 4) for k, v in c.summary().items()}, extra,
              f"n_ref={c.n_ref} n_found={c.n_found} n_matched={c.n_matched}")
    if what in ("all", "sensitivity"):
        rows = sensitivity(png, js)
        print("\nsensitivity (one parameter off its default)")
        print(_fmt(rows, list(rows[0])))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
