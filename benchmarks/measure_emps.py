"""Segmentation accuracy on real micrographs nobody tuned for (EMPS) and on the SEM powder images.

Run from the repository root::

    python benchmarks/measure_emps.py [--emps DIR] [--polarity auto|bright|dark|best] [--name STEM]
    python benchmarks/measure_emps.py --table   # the docs/measurement.md table from the results files

(``--emps`` defaults to ``$BMCTL_EMPS`` or ``../shared/data/emps-dev`` beside the repository (found
from this script's place; a git worktree's is its main checkout's): the 40 EMPS images with their
masks, MIT licence; without that folder (or its masks) the script says so in one line, measures
nothing, leaves the results file as it is and exits with status 2.)

Every image is measured as ``bmctl measure IMAGE --um-per-px 1`` would (data bar, automatic
speck limit, automatic polarity), sizes in pixels (1 px = 1 unit), and scored against its
hand-made instance masks by one-to-one matching: a found particle and a mask instance match
when their intersection over union is > 0.5 (above 0.5 a region can overlap at most one
other region that much, so the matching is unique without an assignment step).

Reference set: mask instances that do not touch the image border and have >= 30 px (the
detection floor); ``bmctl measure`` drops border-cut particles by design (their size is
biased). Found particles that match an ignored instance, or lie mostly (> 50 % of their
area) inside ignored instances, count neither as hits nor as false detections. The score
against all instances (border-cut ones as misses) is written too (``all_instances``).

Reported per image and pooled (sums of hits, false detections and misses) over the two
halves of the 40 images (``A``: even positions in name order, used to choose parameters;
``B``: odd positions, held out) and over all 40: precision, recall, F1; median size ratio
(found / mask equivalent diameter) and median r of matched pairs (both measured the same
way, Crofton perimeter on the pixel mask); the verdict per image and how it separates good
(F1 >= 0.8) from bad (F1 < 0.5) images (and how many good ones are flagged only for having few
particles). The SEM powder images are measured in the same run:
AMPIS against its 238 hand outlines (same matching; reference: outlines not cut by the
border and at least the speck limit), SiO2 (no ground truth) count and median size.
The share of images whose automatic polarity agrees with the masks' (particle median level
against the background 3-10 px around them) is reported by how it was decided.

``--polarity best`` picks, per image, the better of bright and dark by hindsight (F1) — the
upper bound a user who knew the right flag would reach. ``--polarity auto`` (default) is what
``bmctl measure`` does without flags.

Writes ``results/measure_emps.json`` (or ``results/STEM.json``) and prints a summary table;
when ``results/measure_emps_baseline_bright.json`` and ``..._best.json`` exist (this script run
on the segmentation before automatic polarity, see their ``command``), their rows are printed
above for comparison.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.measure.loading import load_image  # noqa: E402
from bmctl.measure.micrograph import measure_micrograph  # noqa: E402
from bmctl.measure.segment import measure_labels, segment  # noqa: E402
from bmctl.validation.measure import match_labels, rasterise, via_polygons  # noqa: E402


def _main_checkout(root: Path) -> Path:
    """The repository's main checkout: ``root``, or where ``root`` is a linked git worktree (its
    ``.git`` a file ``gitdir: MAIN/.git/worktrees/NAME``: the baseline runs of
    ``benchmarks/regenerate.py`` copy this script into one) MAIN, so both find the same data."""
    git = root / ".git"
    try:
        text = git.read_text(encoding="utf-8").strip() if git.is_file() else ""
    except OSError:
        return root
    if not text.startswith("gitdir:"):
        return root
    gitdir = Path(text[len("gitdir:"):].strip())
    gitdir = gitdir if gitdir.is_absolute() else (root / gitdir).resolve()
    return gitdir.parents[2] if gitdir.parent.name == "worktrees" else root


#: the data shared beside the repository (its main checkout, see :func:`_main_checkout`)
SHARED = _main_checkout(ROOT).parent / "shared"
EMPS = Path(os.environ.get("BMCTL_EMPS") or SHARED / "data" / "emps-dev")
DATA = ROOT / "tests" / "data"
MIN_IOU = 0.5
REF_MIN_AREA_PX = 30  # the detection floor of bmctl measure
GOOD_F1, BAD_F1 = 0.8, 0.5


def _has_polarity() -> bool:
    return "polarity" in inspect.signature(segment).parameters


def measure(path, polarity: str, um_per_px: float = 1.0):
    """``bmctl measure`` on one image; labels placed in the full image frame."""
    kw = {}
    if polarity != "auto" or _has_polarity():
        if _has_polarity():
            kw["polarity"] = polarity
        else:  # older versions: bright unless told
            kw["dark_particles"] = polarity == "dark"
    t0 = time.perf_counter()
    res = measure_micrograph(path, um_per_px=um_per_px, **kw)
    dt = time.perf_counter() - t0
    seg = res.segmentation
    full = np.zeros(res.image.shape, dtype=np.int64)
    oy, ox = seg.offset
    full[oy:oy + seg.labels.shape[0], ox:ox + seg.labels.shape[1]] = seg.labels
    return res, full, dt


def true_polarity(img: np.ndarray, ref: np.ndarray) -> str:
    """The particles' polarity by the masks: their median level against the background 3-10 px around them."""
    fg = ref > 0
    ring = ndi.binary_dilation(fg, iterations=10) & ~ndi.binary_dilation(fg, iterations=3)
    if ring.sum() < 50:
        ring = ~fg
    return "bright" if np.median(img[fg]) > np.median(img[ring]) else "dark"


def _border_ids(labels: np.ndarray) -> np.ndarray:
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    return np.unique(edge[edge > 0])


def score(found: np.ndarray, ref: np.ndarray, ignore_ref: np.ndarray) -> dict:
    """Hits, false detections, misses and matched-pair statistics of one image.

    Parameters
    ----------
    found, ref : ndarray of int
        Label images (sequential labels 1..n).
    ignore_ref : ndarray of bool
        Per reference label (index ``label - 1``): not part of the reference set.
    """
    n_f, n_r = int(found.max()), int(ref.max())
    i_f, i_r, _ = match_labels(found, ref, MIN_IOU)
    ignored_found = np.zeros(n_f + 1, bool)
    if n_r:
        ign_mask = np.r_[False, ignore_ref][ref]
        inside = np.bincount(found[ign_mask], minlength=n_f + 1)
        area = np.bincount(found.ravel(), minlength=n_f + 1)
        ignored_found |= inside > 0.5 * np.maximum(area, 1)
        ignored_found[i_f[ignore_ref[i_r - 1]]] = True
    ignored_found[0] = False
    keep = ~ignore_ref[i_r - 1] if i_r.size else np.zeros(0, bool)
    i_f, i_r = i_f[keep], i_r[keep]
    tp = int(i_f.size)
    n_ref = int((~ignore_ref).sum())
    n_found = n_f - int(ignored_found[1:].sum())
    out = {"n_ref": n_ref, "n_found": n_found, "tp": tp, "fp": n_found - tp, "fn": n_ref - tp}
    out.update(_prf(tp, n_found - tp, n_ref - tp))
    if tp:
        tf, tr = measure_labels(found, 1.0), measure_labels(ref, 1.0)
        s_ratio = tf.s_um[i_f - 1] / tr.s_um[i_r - 1]
        out.update({"size_ratio_median": float(np.median(s_ratio)), "r_found_median": float(np.median(tf.r[i_f - 1])),
                    "r_ref_median": float(np.median(tr.r[i_r - 1])), "_ratios": s_ratio.tolist(),
                    "_r_pairs": np.stack([tf.r[i_f - 1], tr.r[i_r - 1]], 1).tolist()})
    else:
        out.update({"size_ratio_median": None, "r_found_median": None, "r_ref_median": None, "_ratios": [], "_r_pairs": []})
    return out


def _prf(tp: int, fp: int, fn: int) -> dict:
    p = tp / (tp + fp) if tp + fp else None
    r = tp / (tp + fn) if tp + fn else None
    f1 = 2 * tp / (2 * tp + fp + fn) if (2 * tp + fp + fn) else None
    return {"precision": p, "recall": r, "f1": f1}


def pool(rows: list[dict]) -> dict:
    tp, fp, fn = (sum(r[k] for r in rows) for k in ("tp", "fp", "fn"))
    ratios = np.concatenate([np.asarray(r["_ratios"], float) for r in rows]) if rows else np.empty(0)
    rp = [np.asarray(r["_r_pairs"], float).reshape(-1, 2) for r in rows]
    rp = np.concatenate(rp) if rp else np.empty((0, 2))
    f1s = [r["f1"] for r in rows if r["f1"] is not None and r["n_ref"] > 0]
    out = {"images": len(rows), "tp": tp, "fp": fp, "fn": fn, **_prf(tp, fp, fn),
           "images_f1_ge_0.5": int(sum(f >= 0.5 for f in f1s)), "images_scored": len(f1s),
           "median_image_f1": float(np.median(f1s)) if f1s else None,
           "size_ratio_median": float(np.median(ratios)) if ratios.size else None,
           "r_found_median": float(np.median(rp[:, 0])) if rp.size else None,
           "r_ref_median": float(np.median(rp[:, 1])) if rp.size else None}
    return out


def verdict_separation(rows: list[dict]) -> dict:
    """Share of bad (F1 < 0.5) images flagged doubtful/unusable, and of good (F1 >= 0.8) ones."""
    scored = [r for r in rows if r["n_ref"] > 0 and r.get("verdict")]
    bad = [r for r in scored if r["f1"] < BAD_F1]
    good = [r for r in scored if r["f1"] >= GOOD_F1]
    flag = (lambda r: r["verdict"] in ("doubtful", "unusable"))
    few_only = (lambda r: flag(r) and bool(r.get("verdict_reasons"))
                and all(str(x).startswith("few particles") for x in r["verdict_reasons"]))
    ok_rows = [r for r in rows if r.get("verdict") == "ok"]
    return {
        "bad_images": len(bad), "bad_flagged": sum(map(flag, bad)),
        "bad_flagged_share": (sum(map(flag, bad)) / len(bad)) if bad else None,
        "good_images": len(good), "good_flagged": sum(map(flag, good)),
        "good_flagged_few_particles_only": sum(map(few_only, good)),
        "good_flagged_share": (sum(map(flag, good)) / len(good)) if good else None,
        "verdict_counts": {v: sum(r.get("verdict") == v for r in rows) for v in ("ok", "doubtful", "unusable")},
        "pooled_ok_only": pool(ok_rows) if ok_rows else None,
    }


def emps_rows(folder: Path, polarity: str, progress=True) -> list[dict]:
    from skimage import io
    from skimage.segmentation import relabel_sequential

    names = sorted(p.name[: -len(".seg.png")] for p in folder.glob("*.seg.png"))
    rows = []
    for k, name in enumerate(names):
        ref = relabel_sequential(io.imread(folder / f"{name}.seg.png").astype(np.int64))[0]
        area = np.bincount(ref.ravel())[1:]
        ignore = np.zeros(int(ref.max()), bool)
        ignore[_border_ids(ref) - 1] = True
        ignore |= area < REF_MIN_AREA_PX
        ignore[area == 0] = True
        allref = np.zeros_like(ignore)
        allref[area == 0] = True
        cands = ("bright", "dark") if polarity == "best" else (polarity,)
        best = None
        for pol in cands:
            res, full, dt = measure(folder / f"{name}.png", pol)
            sc = score(full, ref, ignore)
            if best is None or (sc["f1"] or 0.0) > (best[1]["f1"] or 0.0):
                best = (res, sc, dt, pol, full)
        res, sc, dt, pol, full = best
        sc_all = score(full, ref, allref)
        rep = res.report()
        row = {"image": name, "half": "A" if k % 2 == 0 else "B", **sc, "seconds": round(dt, 3),
               "polarity": rep.get("polarity", {}).get("value") if isinstance(rep.get("polarity"), dict) else (pol if polarity != "auto" else "bright"),
               "polarity_source": rep.get("polarity", {}).get("source") if isinstance(rep.get("polarity"), dict) else "user",
               "n_instances": int(ref.max()),
               "verdict": (rep.get("verdict") or {}).get("value") if isinstance(rep.get("verdict"), dict) else rep.get("verdict"),
               "verdict_reasons": list((rep.get("verdict") or {}).get("reasons") or []) if isinstance(rep.get("verdict"), dict) else [],
               "warnings": [w["code"] for w in rep["warnings"]], "min_area_px": res.min_area_px,
               "true_polarity": true_polarity(load_image(folder / f"{name}.png"), ref), "evidence": rep.get("evidence"),
               "all_instances": {k2: sc_all[k2] for k2 in ("n_ref", "tp", "fp", "fn", "precision", "recall", "f1")}}
        rows.append(row)
        if progress:
            print(f"[{k + 1}/{len(names)}] {name}: F1 {_f(row['f1'])} ({row['tp']}/{row['n_ref']} found {row['n_found']}) "
                  f"size {_f(row['size_ratio_median'])} {row['polarity']} {row['verdict']} {dt:.1f} s", file=sys.stderr)
    return rows


def _f(v, d=2):
    return "-" if v is None else f"{v:.{d}f}"


def ampis(polarity: str) -> dict | None:
    png, js = DATA / "ampis_powder_b.png", DATA / "ampis_masks_validation.json"
    if not png.exists():
        return None
    img = load_image(png)
    ref, border = rasterise(via_polygons(js), img.shape)
    pol = "bright" if polarity == "best" else polarity
    res, full, dt = measure(png, pol)
    area = np.bincount(ref.ravel(), minlength=len(border) + 1)[1:]
    limit = res.min_area_px
    ignore = border | (area < limit) | (area == 0)
    sc = score(full, ref, ignore)
    hand = measure_labels(ref, 1.0)
    rep = res.report()
    hand_ref = float(np.median(hand.s_um[~ignore[: len(hand)]]))
    found_med = float(np.median(res.table.s_um))
    return {
        "image": "ampis_powder_b.png", "reference": f"{int((~ignore).sum())} hand outlines not cut by the border, >= {limit} px",
        **{k: v for k, v in sc.items() if not k.startswith("_")}, "min_area_px": limit, "seconds": round(dt, 3),
        "size_ratio_bias_pct": 100.0 * (sc["size_ratio_median"] - 1.0) if sc["size_ratio_median"] else None,
        "s_median_px": found_med, "hand_s_median_px": float(np.median(hand.s_um)),
        "hand_ref_s_median_px": hand_ref, "s_median_vs_hand_ref_pct": 100.0 * (found_med / hand_ref - 1.0),
        "polarity": (rep.get("polarity") or {}).get("value") if isinstance(rep.get("polarity"), dict) else pol,
        "verdict": (rep.get("verdict") or {}).get("value") if isinstance(rep.get("verdict"), dict) else rep.get("verdict"),
        "warnings": [w["code"] for w in rep["warnings"]],
    }


def sio2(polarity: str) -> dict | None:
    tif = DATA / "sio2_sem_12000x.tif"
    if not tif.exists():
        return None
    kw = {}
    if _has_polarity():
        kw["polarity"] = "bright" if polarity == "best" else polarity
    t0 = time.perf_counter()
    res = measure_micrograph(tif, **kw)
    dt = time.perf_counter() - t0
    rep = res.report()
    return {"image": "sio2_sem_12000x.tif", "count": rep["count"], "s_median_um": rep["s_median_um"], "r_median": rep["r_median"],
            "seconds": round(dt, 3),
            "polarity": (rep.get("polarity") or {}).get("value") if isinstance(rep.get("polarity"), dict) else "bright",
            "verdict": (rep.get("verdict") or {}).get("value") if isinstance(rep.get("verdict"), dict) else rep.get("verdict"),
            "warnings": [w["code"] for w in rep["warnings"]]}


def polarity_accuracy(rows: list[dict]) -> dict:
    """Images whose automatic polarity matches the masks', by how it was decided."""
    out = {}
    for src in ("edges", "evidence", "user", None):
        sel = [r for r in rows if r.get("n_instances", 0) > 0 and (src is None or r.get("polarity_source") == src)]
        if sel:
            out[src or "all"] = {"images": len(sel), "correct": sum(r["polarity"] == r["true_polarity"] for r in sel)}
    return out


def _write_fallback(path: Path, doc: dict) -> None:
    """Versions without bmctl.results (a baseline run on older code): same shape, atomic."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _row(label: str, p: dict) -> str:
    return (f"| {label} | {p['images']} | {_f(p['precision'])} | {_f(p['recall'])} | {_f(p['f1'])} | "
            f"{p['images_f1_ge_0.5']}/{p['images_scored']} | {_f(p['size_ratio_median'], 3)} | "
            f"{_f(p['r_found_median'], 3)} / {_f(p['r_ref_median'], 3)} |")


def doc_table() -> str:
    """The docs/measurement.md table from the results files, its numbers in results markers."""
    from bmctl.results import marked

    out = ["| segmentation, images | precision | recall | F1 | images F1 ≥ <!--in-->0.5<!--/in--> | median size ratio |",
           "|---|---|---|---|---|---|"]
    sets = (("before, no flag (bright)", "measure_emps_baseline_bright", ("half_A", "half_B", "pooled")),
            ("before, better polarity by hindsight", "measure_emps_baseline_best", ("half_A", "half_B", "pooled")),
            ("now, automatic", "measure_emps", ("half_A", "half_B", "pooled", "pooled_not_unusable")))
    label = {"half_A": "A", "half_B": "B", "pooled": "all 40", "pooled_not_unusable": "all but those judged `unusable`"}
    for name, stem, keys in sets:
        f = ROOT / "results" / f"{stem}.json"
        if not f.exists():
            continue
        rec = json.loads(f.read_text(encoding="utf-8"))
        for k in keys:
            p = rec[k]
            lab = label[k] + {"now, automatic": {"half_A": " (parameters chosen here)", "half_B": " (held out)"}}.get(name, {}).get(k, "")
            cells = [marked(stem, f"{k}.{c}", p[c], "{:.2f}") for c in ("precision", "recall", "f1")]
            out.append(f"| {name}: {lab} | " + " | ".join(cells) + f" | {p['images_f1_ge_0.5']}/{p['images_scored']} | "
                       f"{marked(stem, f'{k}.size_ratio_median', p['size_ratio_median'], '{:.3f}')} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--emps", type=Path, default=EMPS, help="folder with NAME.png and NAME.seg.png (default: %(default)s)")
    ap.add_argument("--polarity", choices=("auto", "bright", "dark", "best"), default="auto")
    ap.add_argument("--name", default="measure_emps", help="results file stem under results/ (default: %(default)s)")
    ap.add_argument("--table", action="store_true", help="print the docs/measurement.md table from the results files, run nothing")
    args = ap.parse_args(argv)
    if args.table:
        print(doc_table())
        return 0
    if not args.emps.is_dir() or not any(args.emps.glob("*.seg.png")):  # never a results file of no images
        why = "no such folder" if not args.emps.is_dir() else "no NAME.seg.png masks in it"
        print(f"measure_emps: {args.emps}: {why} (the EMPS images; set --emps or BMCTL_EMPS); nothing measured, "
              f"results/{args.name}.json left as it is", file=sys.stderr)
        return 2
    if args.polarity == "auto" and not _has_polarity():
        args.polarity = "bright"  # older versions: no automatic polarity, bright unless told
    load = os.getloadavg()
    c0, t0 = time.process_time(), time.perf_counter()
    rows = emps_rows(args.emps, args.polarity)
    am, si = ampis(args.polarity), sio2(args.polarity)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    halves = {h: pool([r for r in rows if r["half"] == h]) for h in ("A", "B")}
    pooled = pool(rows)
    accepted = pool([r for r in rows if r.get("verdict") != "unusable"])
    sep = {h: verdict_separation([r for r in rows if r["half"] == h]) for h in ("A", "B")}
    sep["all"] = verdict_separation(rows)
    per_image = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    import bmctl

    command = "python benchmarks/measure_emps.py" + (f" --polarity {args.polarity}" if args.polarity != "auto" else "") + (
        f" --name {args.name}" if args.name != "measure_emps" else "")
    settings = {"polarity": args.polarity, "um_per_px": 1.0, "min_iou": MIN_IOU, "ref_min_area_px": REF_MIN_AREA_PX,
                "good_f1": GOOD_F1, "bad_f1": BAD_F1, "emps_images": len(rows),
                "halves": "A = even positions in name order (parameters chosen here), B = odd positions (held out)"}
    values = {
        "pooled": pooled, "half_A": halves["A"], "half_B": halves["B"], "pooled_not_unusable": accepted,
        "polarity": polarity_accuracy(rows), "verdict": sep, "ampis": am, "sio2": si, "per_image": per_image,
        "timing": {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "loadavg_start": [round(v, 2) for v in load],
                   "loadavg_end": [round(v, 2) for v in os.getloadavg()],
                   "median_image_s": float(np.median([r["seconds"] for r in rows]))},
    }
    try:
        from bmctl.results import results_path, write_results
        out = write_results(args.name, values, settings=settings, command=command)
    except ImportError:
        from datetime import datetime, timezone

        # an older checkout without bmctl.results: still where BMCTL_RESULTS_DIR points (its recorded command)
        out = Path(os.environ.get("BMCTL_RESULTS_DIR") or ROOT / "results") / f"{args.name}.json"
        _write_fallback(out, {"bmctl_version": getattr(bmctl, "__version__", "unknown"), "command": command, "settings": settings,
                              "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), **values})
        results_path = None
    print("| set | images | precision | recall | F1 | images F1>=0.5 | size ratio | r found / mask |")
    print("|---|---|---|---|---|---|---|---|")
    for label, base in (("before, no flag (bright)", "measure_emps_baseline_bright"),
                        ("before, better polarity by hindsight", "measure_emps_baseline_best")):
        f = ROOT / "results" / f"{base}.json"
        if f.exists() and args.name == "measure_emps":
            old = json.loads(f.read_text(encoding="utf-8"))
            for h in ("half_A", "half_B", "pooled"):
                print(_row(f"{label}: {h.replace('_', ' ')}", old[h]))
    for label, p in (("A (tuning)", halves["A"]), ("B (held out)", halves["B"]), ("all 40", pooled),
                     ("all but unusable", accepted)):
        print(_row(label, p))
    v = sep["all"]
    pa = values["polarity"].get("all")
    if pa:
        print(f"polarity: {pa['correct']}/{pa['images']} images as the masks say; " + ", ".join(
            f"{k}: {q['correct']}/{q['images']}" for k, q in values["polarity"].items() if k != "all"))
    if sum(v["verdict_counts"].values()):
        print(f"verdict: {v['verdict_counts']}; bad images (F1 < {BAD_F1}) flagged {v['bad_flagged']}/{v['bad_images']}, "
              f"good images (F1 >= {GOOD_F1}) flagged {v['good_flagged']}/{v['good_images']}"
              f" ({v.get('good_flagged_few_particles_only', 0)} only for few particles)")
    if am:
        print(f"AMPIS: precision {_f(am['precision'])} recall {_f(am['recall'])} F1 {_f(am['f1'])} matched size ratio "
              f"{_f(am['size_ratio_median'], 3)}; median s {am['s_median_px']:.1f} px vs {am['hand_ref_s_median_px']:.1f} px "
              f"by hand ({am['reference']}), {am['polarity']}, {am['verdict']}, {am['seconds']:.1f} s")
    if si:
        print(f"SiO2: {si['count']} particles, median s {si['s_median_um']:.3f} µm, {si['polarity']}, {si['verdict']}, {si['seconds']:.1f} s")
    print(f"wrote {out} ({wall:.0f} s wall, {cpu:.0f} s CPU, load {load[0]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
