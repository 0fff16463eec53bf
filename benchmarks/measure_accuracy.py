"""Accuracy of the micrograph measurement: perimeter bias, synthetic images, the SEM powder images.

Run from the repository root, one part at a time (each writes ``results/measure_<PART>.json``)::

    python benchmarks/measure_accuracy.py perimeter     # estimator bias on pixel masks; AMPIS hand polygons
    python benchmarks/measure_accuracy.py synthetic     # known-truth images, resolution sweep, sampler noise
    python benchmarks/measure_accuracy.py real          # AMPIS vs hand outlines, SiO2, speck-limit table
    python benchmarks/measure_accuracy.py sensitivity   # one segmentation parameter at a time off its default
    python benchmarks/measure_accuracy.py PART --table  # print the docs/measurement.md tables from the file

The real images are ``tests/data/ampis_powder_b.png`` (+ ``ampis_masks_validation.json``, hand
outlines) and ``tests/data/sio2_sem_12000x.tif``, or the same names under ``$BMCTL_MICROGRAPHS``
(default ``../shared/data/micrographs`` beside the repository, found from this script's place);
without them a part that needs them says so in one line (naming the folder, and whether it is
there), writes nothing and exits with status 2.
All randomness is seeded (``numpy.random.default_rng``); the numbers are reproducible.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.results import load_results, marked, write_results  # noqa: E402

PARTS = ("perimeter", "synthetic", "real", "sensitivity")
SWEEP_D = (5, 7, 10, 14, 20, 28, 40)
R_BINS = (0.0, 0.05, 0.10, 0.15, 0.20)
SPECK_LIMITS = (15, 30, 60, 80, 120, 160, 240)
SYN_SEED = 7


#: where the real images are looked for after tests/data: the data shared beside the repository
MICROGRAPHS = Path(os.environ.get("BMCTL_MICROGRAPHS") or ROOT.parent / "shared" / "data" / "micrographs")


def _data(name: str) -> Path | None:
    for folder in (ROOT / "tests" / "data", MICROGRAPHS):
        if (folder / name).exists():
            return folder / name
    return None


def _ampis() -> tuple[Path, Path] | None:
    png, js = _data("ampis_powder_b.png"), _data("ampis_masks_validation.json")
    return (png, js) if png and js else None


def _pct(d: dict, *keys: str) -> dict:
    """``d`` with ``KEY_pct`` = 100 x ``KEY`` added for relative values (the docs show them in %)."""
    for k in keys:
        if d.get(k) is not None:
            d[f"{k}_pct"] = 100.0 * d[k]
    return d


def _med(v) -> float | None:
    v = np.asarray(v, float)
    return float(np.median(v)) if v.size else None


# --- perimeter -----------------------------------------------------------------------------------

def run_perimeter() -> tuple[dict, dict]:
    from bmctl.measure.perimeter import bias_study, perimeter
    from bmctl.validation.measure import polygon_lengths, via_polygons

    rows = bias_study()  # defaults: 5-80 px, disc / ellipse q=2 / warped r=0.10, 40 placements, seed 0
    rows = [_pct(r, "mean", "std", "area_err", "area_std") for r in rows]
    cro = [r for r in rows if r["method"] == "crofton"]
    pix = [r for r in rows if r["method"] == "pixel"]
    summary = {
        "crofton_max_abs_bias_from_7px": max(abs(r["mean"]) for r in cro if r["d_px"] >= 7),
        "crofton_max_abs_bias_disc_from_7px": max(abs(r["mean"]) for r in cro if r["d_px"] >= 7 and r["kind"] == "disc"),
        "crofton_max_abs_bias_from_14px": max(abs(r["mean"]) for r in cro if r["d_px"] >= 14),
        "pixel_min_bias": min(r["mean"] for r in pix), "pixel_max_bias": max(r["mean"] for r in pix),
        "pixel_min_r_err": min(r["r_err"] for r in pix), "pixel_max_r_err": max(r["r_err"] for r in pix),
    }
    _pct(summary, *[k for k in summary if "bias" in k])
    hand = None
    files = _ampis()
    if files:
        from skimage import draw

        polys = via_polygons(files[1])
        area, length = polygon_lengths(polys)
        s = 2 * np.sqrt(area / np.pi)
        err = {"crofton": [], "pixel": []}
        for x, y in polys:
            x0, y0 = x.min() - 3, y.min() - 3
            m = draw.polygon2mask((int(y.max() - y0) + 4, int(x.max() - x0) + 4), np.c_[y - y0, x - x0])
            for k in err:
                err[k].append(perimeter(m, k))
        big = s >= 20
        ec, ep = np.array(err["crofton"]) / length - 1, np.array(err["pixel"]) / length - 1
        hand = {"outlines": len(polys), "outlines_ge_20px": int(big.sum()),
                "crofton_median_err": _med(ec[big]), "crofton_p90_abs_err": float(np.percentile(np.abs(ec[big]), 90)),
                "pixel_median_err": _med(ep[big]), "crofton_median_err_below_20px": _med(ec[~big])}
        _pct(hand, "crofton_median_err", "crofton_p90_abs_err", "pixel_median_err", "crofton_median_err_below_20px")
    values = {"rows": rows, "summary": summary, "ampis_hand_polygons": hand}
    settings = {"diameters_px": [5, 7, 10, 14, 20, 40, 80], "kinds": ["disc", "ellipse q=2", "warped r=0.10"],
                "placements": 40, "seed": 0, "hand_polygons_min_s_px": 20}
    return values, settings


def table_perimeter(rec: dict) -> str:
    rows = rec["rows"]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    f = "measure_perimeter"
    out = ["| shape | s (px) | " + " | ".join(f"{m}: dL/L % (r err)" for m in methods) + " | area err % |",
           "|" + "---|" * (len(methods) + 3)]
    for kind, d in dict.fromkeys((r["kind"], r["d_px"]) for r in rows):
        cells, area = [], ""
        for m in methods:
            i, row = next((i, r) for i, r in enumerate(rows) if r["kind"] == kind and r["d_px"] == d and r["method"] == m)
            cells.append(f"{_pm(f, f'rows.{i}.mean', row['mean'])} ± {marked(f, f'rows.{i}.std_pct', 100 * row['std'], '{:.1f}')} "
                         f"({marked(f, f'rows.{i}.r_err', row['r_err'], '{:+.3f}')})")
            area = f"{_pm(f, f'rows.{i}.area_err', row['area_err'])} ± {marked(f, f'rows.{i}.area_std_pct', 100 * row['area_std'], '{:.1f}')}"
        out.append(f"| {kind} | {d} | " + " | ".join(cells) + f" | {area} |")
    return "\n".join(out)


# --- synthetic -----------------------------------------------------------------------------------

def _sweep(k_range=None, keep_r=False):
    from bmctl.validation.measure import synthetic_comparison

    rows, rbins = [], []
    for d in SWEEP_D:  # the same seeds and counts as bmctl.validation.measure.resolution_sweep
        rng = np.random.default_rng([0, int(d)])
        kw = dict(n=int(min(150, 60 * (40 / d) ** 1.5)), shape=(384, 384), s_px=(0.95 * d, 1.05 * d))
        if k_range is not None:
            kw["k_range"] = k_range
        c = synthetic_comparison(rng, 2, segment_kw={"min_area_px": 8}, **kw)
        rows.append(_pct({"d_px": d, "n_ref": c.n_ref, **c.summary()}, "s_mae", "s_bias"))
        if keep_r:
            b = np.digitize(c.r_ref, R_BINS[1:-1])
            rbins.append({"d_px": d, "r_bias": [_med(c.r_err[b == j]) for j in range(len(R_BINS) - 1)],
                          "n": [int((b == j).sum()) for j in range(len(R_BINS) - 1)]})
    return rows, rbins


def _sampler_noise() -> dict:
    from bmctl.measure.sampler import NOISE, micrograph_sample

    rng = np.random.default_rng(3)
    s_err, r_err = [], []
    for r0 in (0.05, 0.075, 0.10):
        t = micrograph_sample(np.full(10, 10.0), np.full(10, r0), 20000, rng)
        s_err.append(t.s_um / 10.0 - 1)
        r_err.append(t.r - r0)
    s_err, r_err = np.concatenate(s_err), np.concatenate(r_err)
    return _pct({"noise": NOISE, "s_mae": _med(np.abs(s_err)), "r_mae": _med(np.abs(r_err)), "r_std": float(np.std(r_err))},
                "s_mae")


def run_synthetic() -> tuple[dict, dict]:
    from bmctl.validation.measure import synthetic_comparison

    pops = {}
    for key, s_px in (("s10_14", (10.0, 14.0)), ("s20_40", (20.0, 40.0))):
        c = synthetic_comparison(np.random.default_rng(SYN_SEED), 2, n=60, shape=(384, 384), s_px=s_px)
        pops[key] = _pct({"s_px": list(s_px), "n_ref": c.n_ref, **c.summary()}, "s_mae", "s_bias")
    sweep, rbins = _sweep(keep_r=True)
    sweep7, _ = _sweep(k_range=(3, 7))
    values = {"populations": pops, "sweep": sweep, "sweep_k3_7": sweep7, "sweep_r_bins": rbins,
              "sampler": _sampler_noise()}
    settings = {"populations": "2 images x 60 particles, 384x384 px, r ~ U(0, 0.2), seed 7",
                "sweep": "sizes +-5 %, 2 images per size, min_area_px 8, seed default_rng([0, d])",
                "sweep_diameters_px": list(SWEEP_D), "r_bins": list(R_BINS),
                "sampler": "fast path, 20000 particles at each of r = 0.05, 0.075, 0.10, s = 10 um, no pixel size, seed 3"}
    return values, settings


def _sweep_table(rec: dict, key: str) -> str:
    f = "measure_synthetic"
    out = ["| s (px) | matched | median abs. s err % | s bias % | median abs. r err | r bias |", "|---|---|---|---|---|---|"]
    for i, r in enumerate(rec[key]):
        out.append(f"| {r['d_px']} | {marked(f, f'{key}.{i}.matched', r['matched'], '{:.2f}')} | "
                   f"{marked(f, f'{key}.{i}.s_mae_pct', 100 * r['s_mae'], '{:.1f}')} | {_pm(f, f'{key}.{i}.s_bias', r['s_bias'])} | "
                   f"{marked(f, f'{key}.{i}.r_mae', r['r_mae'], '{:.3f}')} | {marked(f, f'{key}.{i}.r_bias', r['r_bias'], '{:+.3f}')} |")
    return "\n".join(out)


def table_synthetic(rec: dict) -> str:
    f = "measure_synthetic"
    out = ["| population | matched | median abs. s err % | s bias % | median abs. r err | r bias |", "|---|---|---|---|---|---|"]
    for key, p in rec["populations"].items():
        lo, hi = p["s_px"]
        out.append(f"| s = {lo:g}–{hi:g} px, r ~ U(0, <!--in-->0.2<!--/in-->), 2 images × <!--in-->60<!--/in--> | {marked(f, f'populations.{key}.matched', p['matched'], '{:.2f}')} | "
                   f"{marked(f, f'populations.{key}.s_mae_pct', 100 * p['s_mae'], '{:.1f}')} | {_pm(f, f'populations.{key}.s_bias', p['s_bias'])} | "
                   f"{marked(f, f'populations.{key}.r_mae', p['r_mae'], '{:.3f}')} | {marked(f, f'populations.{key}.r_bias', p['r_bias'], '{:+.3f}')} |")
    out += ["", "Lobes k = 3–5 (renderer default):", "", _sweep_table(rec, "sweep"),
            "", "Finer boundary detail, k = 3–7 lobes:", "", _sweep_table(rec, "sweep_k3_7"), "",
            "Median r error by true r (k = 3–5):", "",
            "| s (px) | " + " | ".join(f"r <!--in-->{a:.2f}<!--/in-->–<!--in-->{b:.2f}<!--/in-->" for a, b in zip(R_BINS[:-1], R_BINS[1:])) + " |",
            "|---|" + "---|" * (len(R_BINS) - 1)]
    for i, row in enumerate(rec["sweep_r_bins"]):
        out.append(f"| {row['d_px']} | " + " | ".join(
            marked(f, f"sweep_r_bins.{i}.r_bias.{j}", v, "{:+.3f}") for j, v in enumerate(row["r_bias"])) + " |")
    return "\n".join(out)


# --- real images ---------------------------------------------------------------------------------

def _warn(rep: dict) -> dict:
    return {w["code"]: w["value"] for w in rep["warnings"]}


def run_real() -> tuple[dict, dict]:
    from bmctl.measure.micrograph import measure_micrograph
    from bmctl.validation.measure import hand_comparison

    values: dict = {"ampis": None, "sio2": None, "speck": {}}
    files = _ampis()
    if files:
        c, extra = hand_comparison(*files)
        values["ampis"] = {"n_outlines": extra["n_outlines"], "n_ref": c.n_ref, "n_found": c.n_found,
                           "n_matched": c.n_matched, **c.summary()}
        _pct(values["ampis"], "s_mae", "s_bias")
        rep = measure_micrograph(files[0], um_per_px=1.0).report()
        values["ampis"]["auto"] = {"min_area_px": rep["min_area_px"], "count": rep["count"], "s_median_px": rep["s_median_um"],
                                   "warnings": _warn(rep), "verdict": rep["verdict"]["value"],
                                   "warnings_pct": {k: 100 * v for k, v in _warn(rep).items()}}
    tif = _data("sio2_sem_12000x.tif")
    if tif:
        runs = {"default": {}, "keep_info_bar": {"keep_info_bar": True}, "crop": {"crop": "0:423,:", "um_per_px": 0.0368}}
        values["sio2"] = {}
        for key, kw in runs.items():
            rep = measure_micrograph(tif, **kw).report()
            values["sio2"][key] = {"count": rep["count"], "s_median_um": rep["s_median_um"], "r_median": rep["r_median"],
                                   "um_per_px": rep["scale"]["um_per_px"], "scale_source": rep["scale"]["source"],
                                   "info_bar_first_row": rep["info_bar_first_row"], "min_area_px": rep["min_area_px"],
                                   "scale_bar": rep["scale_bar"], "polarity": rep["polarity"],
                                   "verdict": rep["verdict"]["value"], "warnings": _warn(rep),
                                   "warnings_pct": {k: 100 * v for k, v in _warn(rep).items()}}
    for key, path, kw in (("ampis", files[0] if files else None, {"um_per_px": 1.0}), ("sio2", tif, {})):
        if path is None:
            continue
        rows = []
        for lim in SPECK_LIMITS:
            rep = measure_micrograph(path, min_area_px=lim, **kw).report()
            rows.append({"min_area_px": lim, "count": rep["count"], "s_median": rep["s_median_um"]})
        values["speck"][key] = rows
    settings = {"ampis": "tests/data/ampis_powder_b.png vs 238 hand outlines, IoU > 0.5, reference: interior outlines >= 30 px; "
                         "auto: measure_micrograph(um_per_px=1)",
                "sio2": "tests/data/sio2_sem_12000x.tif: no flags; --keep-info-bar; --crop 0:423,: --um-per-px 0.0368",
                "speck_limits_px": list(SPECK_LIMITS)}
    return values, settings


def table_real(rec: dict) -> str:
    f = "measure_real"
    out = []
    a = rec.get("ampis")
    if a:
        out += ["| | value |", "|---|---|",
                f"| outlines matched (IoU > <!--in-->0.5<!--/in-->) | {marked(f, 'ampis.n_matched', a['n_matched'], '{:d}')} / "
                f"{marked(f, 'ampis.n_ref', a['n_ref'], '{:d}')} = {marked(f, 'ampis.matched', a['matched'], '{:.2f}')} |",
                f"| precision (found particles that match an outline) | {marked(f, 'ampis.n_matched', a['n_matched'], '{:d}')} / "
                f"{marked(f, 'ampis.n_found', a['n_found'], '{:d}')} = "
                f"{marked(f, 'ampis.precision', a['precision'], '{:.2f}')} |",
                f"| matched: median abs. s error | {marked(f, 'ampis.s_mae_pct', 100 * a['s_mae'], '{:.1f}')} % "
                f"(bias {_pm(f, 'ampis.s_bias', a['s_bias'])} %) |",
                f"| matched: median abs. r error | {marked(f, 'ampis.r_mae', a['r_mae'], '{:.3f}')} (bias "
                f"{marked(f, 'ampis.r_bias', a['r_bias'], '{:+.3f}')}; hand r median {marked(f, 'ampis.r_ref_median', a['r_ref_median'], '{:.3f}')}) |", ""]
    sp = rec.get("speck", {})
    if sp:
        lims = [r["min_area_px"] for r in next(iter(sp.values()))]
        out += ["| limit (px) | " + " | ".join(map(str, lims)) + " | auto |", "|---|" + "---|" * (len(lims) + 1)]
        for key, label, fmt in (("ampis", "AMPIS: count / median s (px)", "{:.1f}"), ("sio2", "SiO2: count / median s (µm)", "{:.2f}")):
            if key not in sp:
                continue
            cells = [f"{marked(f, f'speck.{key}.{i}.count', r['count'], '{:d}')} / {marked(f, f'speck.{key}.{i}.s_median', r['s_median'], fmt)}" for i, r in enumerate(sp[key])]
            auto = rec["ampis"]["auto"] if key == "ampis" else rec["sio2"]["default"]
            sk = "ampis.auto.s_median_px" if key == "ampis" else "sio2.default.s_median_um"
            med = auto.get("s_median_px", auto.get("s_median_um"))
            ak = sk.rsplit(".", 1)[0]
            cells.append(f"{marked(f, ak + '.min_area_px', auto['min_area_px'], '{:d}')} px: "
                         f"{marked(f, ak + '.count', auto['count'], '{:d}')} / {marked(f, sk, med, fmt)}")
            out.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(out)


# --- sensitivity ---------------------------------------------------------------------------------

def run_sensitivity() -> tuple[dict, dict]:
    from bmctl.validation.measure import sensitivity

    files = _ampis()
    rows = sensitivity(*files, seed=SYN_SEED) if files else None
    keys = {"real matched": "real_matched", "real precision": "real_precision", "real s_mae": "real_s_mae",
            "real r_mae": "real_r_mae", "syn matched": "syn_matched", "syn s_mae": "syn_s_mae", "syn r_mae": "syn_r_mae"}
    rows = None if rows is None else [{"variant": r["variant"], **{keys[k]: v for k, v in r.items() if k in keys}} for r in rows]
    return {"rows": rows}, {"real": "AMPIS vs hand outlines", "synthetic": "2 images x 60 particles, s = 10-40 px, seed 7"}


def table_sensitivity(rec: dict) -> str:
    f = "measure_sensitivity"
    cols = ("real_matched", "real_precision", "real_s_mae", "real_r_mae", "syn_matched", "syn_s_mae", "syn_r_mae")
    out = ["| variant | real matched | real precision | real s err | real r err | syn matched | syn s err | syn r err |",
           "|---|" + "---|" * len(cols)]
    for i, r in enumerate(rec["rows"] or []):
        out.append(f"| {r['variant']} | " + " | ".join(marked(f, f"rows.{i}.{c}", r[c], "{:.3f}") for c in cols) + " |")
    return "\n".join(out)


# --- main ----------------------------------------------------------------------------------------

def _pm(f: str, key: str, frac: float) -> str:
    """A signed relative value (fraction ``frac``, stored also as ``KEY_pct``), shown in % with one decimal."""
    return marked(f, key + "_pct", 100 * frac, "{:+.1f}")


RUN = {"perimeter": run_perimeter, "synthetic": run_synthetic, "real": run_real, "sensitivity": run_sensitivity}
TABLE = {"perimeter": table_perimeter, "synthetic": table_synthetic, "real": table_real, "sensitivity": table_sensitivity}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=PARTS)
    ap.add_argument("--table", action="store_true", help="print the docs table from results/measure_PART.json, run nothing")
    a = ap.parse_args(argv)
    name = f"measure_{a.part}"
    if not a.table:
        need = {"perimeter": ("ampis_masks_validation.json",), "synthetic": (),
                "real": ("ampis_powder_b.png", "ampis_masks_validation.json", "sio2_sem_12000x.tif"),
                "sensitivity": ("ampis_powder_b.png", "ampis_masks_validation.json")}[a.part]
        missing = [n for n in need if _data(n) is None]
        if missing:  # never overwrite a results file with a partial one
            absent = "" if MICROGRAPHS.is_dir() else ", no such folder; set BMCTL_MICROGRAPHS"
            print(f"measure_accuracy: {', '.join(missing)} not found in tests/data or {MICROGRAPHS}{absent}; "
                  f"nothing measured, results/{name}.json left as it is", file=sys.stderr)
            return 2
        load, t0 = os.getloadavg(), time.perf_counter()
        values, settings = RUN[a.part]()
        values["timing"] = {"wall_s": round(time.perf_counter() - t0, 1), "loadavg_start": [round(v, 2) for v in load]}
        out = write_results(name, values, settings=settings, command=f"python benchmarks/measure_accuracy.py {a.part}")
        print(f"wrote {out} ({values['timing']['wall_s']} s)", file=sys.stderr)
    print(TABLE[a.part](load_results(name)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
