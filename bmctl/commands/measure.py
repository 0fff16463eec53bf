"""Segment micrographs into per-particle size s and aspect ratio r (and pass particle tables through).

Each IMAGE is measured by :func:`bmctl.measure.micrograph.measure_micrograph`: the data bar at
the bottom is detected and excluded, the pixel size is read from the instrument's metadata
(or from the scale bar, given its length), specks are dropped, and the particles measured in
micrometres. A ``.csv`` argument is read as a particle table instead
(:func:`bmctl.measure.tables.read_table`) and normalised. All inputs are pooled into one table
``particle_id,image,x_um,y_um,area_um2,perimeter_um,s_um,r`` written atomically to ``--out``,
with an overlay PNG per image (outlines and particle ids) and ``measure.json`` (scale and how
it was found, exclusions, polarity, counts, warnings, the reliability verdict) beside it; nothing
is written when any input is bad. Each file is given once: two arguments that name one file (the
same path twice, ``a.png ./a.png``, or one file by two names: a symbolic or hard link) are refused
before any input is read, naming both (its particles would be counted twice). Per image the
polarity (particles brighter or darker than the background, decided per image unless
``--dark-particles`` or ``--bright-particles`` is given) and the verdict (``ok``, ``doubtful``,
``unusable``) go to stderr with the warnings.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from ..errors import InputError
from ..naming import naming
from ._args import LIBRARY_FLAGS, float_arg, int_arg, output_path

#: default --min-area-px; equals bmctl.measure.segment.MIN_AREA_PX (a test checks), kept here so that
#: building the parser does not import the image stack
MIN_AREA_PX = 30
#: default --min-particles; equals bmctl.measure.quality.MIN_PARTICLES (a test checks)
MIN_PARTICLES = 5


def _min_area(text: str):
    if text == "auto":
        return "auto"
    try:
        if "_" in text:  # int() reads "4_0" as 40
            raise ValueError
        v = int(text)
    except ValueError:
        raise InputError(f"--min-area-px: expected a number of px or 'auto' (got {text!r})") from None
    if v < 1:
        raise InputError(f"--min-area-px: must be >= 1 (got {v})")
    return v


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``measure`` arguments."""
    parser.add_argument("inputs", nargs="+", metavar="IMAGE",
                        help="micrograph(s) (png/tif/...) or particle table(s) (.csv), each file once")
    parser.add_argument("--um-per-px", type=float_arg("--um-per-px"), default=None, metavar="X", help="pixel size in micrometres (overrides the image metadata)")
    parser.add_argument("--scale-bar-um", type=float_arg("--scale-bar-um"), default=None, metavar="L",
                        help="length of the scale bar on the image, in µm (used when the metadata has no pixel size)")
    parser.add_argument("--out", default=None, metavar="CSV", help="write the pooled particle table here (overlays and measure.json beside it)")
    parser.add_argument("--min-area-px", type=_min_area, default="auto", metavar="N",
                        help="drop blobs below N px (default auto: 1/100 of the area-weighted median particle area, at least 30)")
    parser.add_argument("--min-particles", type=int_arg("--min-particles", 0), default=MIN_PARTICLES, metavar="N",
                        help=f"verdict at least doubtful for an image with fewer than N particles (default {MIN_PARTICLES}; 0: no limit)")
    parser.add_argument("--crop", default=None, metavar="Y0:Y1,X0:X1", help="keep this window only")
    parser.add_argument("--keep-info-bar", action="store_true", help="do not detect and exclude a data bar (at the bottom or a banner at the top)")
    parser.add_argument("--no-overlay", action="store_true", help="do not write the overlay PNGs")
    pol = parser.add_mutually_exclusive_group()
    pol.add_argument("--dark-particles", action="store_true", help="particles darker than the background (default: decided per image)")
    pol.add_argument("--bright-particles", action="store_true", help="particles brighter than the background (default: decided per image)")
    parser.add_argument("--no-flatten", action="store_true", help="skip the background flattening")
    parser.add_argument("--no-progress", action="store_true",
                        help=f"no progress lines on stderr (printed when the images' estimated work is over "
                             f"{PROGRESS_AFTER_S:g} s)")


def _polarity_text(res) -> str:
    seg = res.segmentation
    how = {"user": "as given", "edges": f"edge vote {seg.polarity_vote:.2f}" if seg.polarity_vote is not None else "",
           "evidence": "near-tie of the edge vote, decided by the readings' verdicts and counts"}.get(seg.polarity_source, seg.polarity_source)
    return f"{seg.polarity} particles ({how})"


def _count(n: int) -> str:
    """``n`` particles, in words ("1 particle", "31 particles")."""
    return f"{n} particle{'' if n == 1 else 's'}"


def _is_table(path: str) -> bool:
    return Path(path).suffix.lower() == ".csv"


def _overlay_names(images, folder: Path) -> list[Path]:
    """The overlay written in ``folder`` for each of ``images`` (paths, in order): ``STEM.overlay.png``,
    numbered from the second image of the same stem on."""
    names, seen = [], set()
    for image in images:
        stem = Path(image).stem
        cand, k = f"{stem}.overlay.png", 2
        while cand in seen:
            cand, k = f"{stem}-{k}.overlay.png", k + 1
        seen.add(cand)
        names.append(folder / cand)
    return names


def _refuse_same_inputs(inputs) -> None:
    """Refuse two inputs that are one file, naming both: the same path, the same resolved path (a
    symbolic link), or the same file by another name (a hard link); its particles would be counted
    twice. Nothing is read: called before any input is opened.

    Parameters
    ----------
    inputs : list of str
        The IMAGE arguments, in order.

    Raises
    ------
    InputError
        Two of them name one file.
    """
    from ..io import repeated_file
    from ..measure.names import path_text

    pair = repeated_file(inputs)
    if pair is not None:
        first, p = inputs[pair[0]], inputs[pair[1]]
        how = "" if first == p else f" (the same file as {path_text(first)})"
        raise InputError(f"{path_text(p)}: given twice{how}; give each image or table once "
                         "(its particles would be counted twice)")


def _check_output_names(args) -> None:
    """Refuse, before any work, an output set whose files would overwrite an input or each other: the
    table ``--out``, ``measure.json`` beside it and each image's overlay (unless ``--no-overlay``)."""
    from ..io import same_file
    from ..measure.names import path_text

    out = os.fspath(args.out)
    for inp in args.inputs:
        if same_file(out, inp):
            also = "" if os.path.normpath(out) == os.path.normpath(inp) else f" ({path_text(inp)})"
            raise InputError(f"--out: {path_text(out)} is one of the inputs{also}")
    folder = Path(out).parent
    beside = [(os.fspath(folder / "measure.json"), "the measure.json written beside it", "")]  # (path, what, hint)
    if not args.no_overlay:
        images = [p for p in args.inputs if not _is_table(p)]
        beside += [(os.fspath(png), f"the overlay of {path_text(img)}", " or pass --no-overlay")
                   for img, png in zip(images, _overlay_names(images, folder))]
    for path, what, hint in beside:
        if os.path.realpath(path) == os.path.realpath(out):
            raise InputError(f"--out: {path_text(out)} would be overwritten by {what}; choose another name{hint}")
        for inp in args.inputs:
            if same_file(path, inp):
                raise InputError(f"--out: {what} ({path_text(path)}) would overwrite the input {path_text(inp)}; "
                                 f"choose another folder for --out{hint}")
    for k, (path, what, hint) in enumerate(beside):
        for other, other_what, _ in beside[k + 1:]:
            if os.path.realpath(path) == os.path.realpath(other):
                raise InputError(f"--out: {what} ({path_text(path)}) and {other_what} ({path_text(other)}) are the "
                                 f"same file; choose another folder for --out{hint}")


def _finite(value):
    """``value`` (a ``measure.json`` document) with every float that is not finite (the median of
    no particles) as ``None``: JSON has no NaN, and a strict reader refuses one."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


#: progress lines on stderr when the images' estimated CPU time (:func:`bmctl.work.measure_work`) is over this
PROGRESS_AFTER_S = 5.0


def _check_work(images) -> dict:
    """Refuse images whose segmentation would need more memory or CPU than the work budget
    (:func:`bmctl.work.measure_work` on the headers' pixel counts), before any is decoded; the
    pixel count of each image (``{path: pixels}``)."""
    from ..io import check_input_file
    from ..measure.loading import check_header, image_header, verify_image
    from ..measure.names import path_text
    from ..work import check_work, measure_work

    for p in images:  # before any header is opened: opening a FIFO's reader waits for a writer
        check_input_file(p)
    heads = [(image_header(p), p) for p in images]
    for head, p in heads:  # the reader's own limits first: no budget flag lifts them
        check_header(head, path_text(p))
    for p in images:  # a truncated file is named now, not after the images before it are measured
        verify_image(p, path_text(p))
    px = [(head.pixels or 0, p) for head, p in heads]
    if not px:
        return {}
    most, name = max(px, key=lambda q: q[0])
    pixels = {p: n for n, p in px}
    check_work(measure_work([n for n, _ in px]),
               f"{path_text(name)} ({most:,} px{f' of {sum(n for n, _ in px):,} in {len(px)} images' if len(px) > 1 else ''}; "
               "downsample or crop the file first)")
    return pixels


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args: argparse.Namespace) -> int:
    """Measure all inputs, print a summary and warnings, write ``--out`` and what goes beside it."""
    import numpy as np

    from ..io import output_set
    from ..measure.micrograph import measure_micrograph
    from ..measure.names import path_text
    from ..measure.scale import check_scale
    from ..measure.tables import ParticleLocations, ParticleTable, check_table, read_table
    from ..work import measure_work
    from ._model import progress_printer

    scale = check_scale(args.um_per_px) if args.um_per_px is not None else None
    bar_um = check_scale(args.scale_bar_um, "scale_bar_um") if args.scale_bar_um is not None else None
    for given, flag in ((scale, "--um-per-px"), (bar_um, "--scale-bar-um")):
        if given is not None and all(_is_table(p) for p in args.inputs):  # a pixel size nothing would use
            raise InputError(f"{flag}: every input is a particle table (.csv, sizes in µm already); it applies "
                             "to micrographs only")
    if args.out is not None:
        output_path(args.out, folder=False)
        _check_output_names(args)
    tables, locs, lines, results, reports, warned = [], [], [], [], [], []
    next_id = 1
    _refuse_same_inputs(args.inputs)  # one image twice would be counted twice
    pixels = _check_work([p for p in args.inputs if not _is_table(p)])
    long = measure_work(list(pixels.values()))["cpu_s"] > PROGRESS_AFTER_S
    progress = progress_printer("measure") if long and not args.no_progress else None
    for i, path in enumerate(args.inputs):
        name = path_text(path)  # printed and in the table: bytes that are not UTF-8 as escapes
        if progress and path in pixels:
            progress(f"input {i + 1} of {len(args.inputs)}: {name} ({pixels[path] / 1e6:.1f} Mpx)")
        if _is_table(path):
            t = read_table(path)
            x = y = np.full(len(t), np.nan)
            lines.append(f"{name}: {_count(len(t))} (table)")
            reports.append({"table": path, "count": len(t)})
        else:
            polarity = "dark" if args.dark_particles else "bright" if args.bright_particles else "auto"
            res = measure_micrograph(path, um_per_px=scale, scale_bar_um=bar_um, keep_info_bar=args.keep_info_bar,
                                     min_area_px=args.min_area_px, crop=args.crop, flatten=not args.no_flatten,
                                     polarity=polarity, min_particles=args.min_particles)
            t, x, y = check_table(res.table, path), res.x_um, res.y_um
            results.append(res)
            reports.append(res.report())
            excl = f", data bar from row {res.info_bar_row} excluded" if res.info_bar_row is not None else ""
            if res.info_bar_top_last_row is not None:
                excl += f", data bar rows 0-{res.info_bar_top_last_row} excluded"
            lines.append(f"{name}: {_count(len(t))}; {res.scale.um_per_px:.5g} µm/px from {res.scale.source} "
                         f"({res.scale.detail}){excl}; min area {res.min_area_px} px")
            warned.append(f"bmctl: {name}: {_polarity_text(res)}; verdict {res.verdict}"
                          + (f" ({'; '.join(res.verdict_reasons)})" if res.verdict_reasons else ""))
            warned += [f"bmctl: warning: {name}: {w.message}" for w in res.warnings]
        ids = np.arange(next_id, next_id + len(t))
        next_id += len(t)
        tables.append(t)
        locs.append(ParticleLocations(ids, (name,) * len(t), np.asarray(x, float), np.asarray(y, float)))
    table = ParticleTable.concat(tables)
    if len(table) == 0:
        if not results:  # tables only
            raise InputError(f"{args.inputs[0]}: no particles found (check the scale, --min-area-px, --crop)")
        # the pixel size plays no part in finding particles: name what does, and how the image was read
        first = results[0]
        more = {1: "", 2: " (nor in the other image)"}.get(len(results), f" (nor in the other {len(results) - 1} images)")
        raise InputError(f"{path_text(first.name)}: no particles found{more}: read as {_polarity_text(first)}; "
                         "check --min-area-px, --crop, or the polarity (--dark-particles / --bright-particles)")
    if progress:
        progress("measured; writing" if args.out else "measured")
    loc = ParticleLocations(np.concatenate([q.particle_id for q in locs]), sum((q.image for q in locs), ()),
                            np.concatenate([q.x_um for q in locs]), np.concatenate([q.y_um for q in locs]))
    written = []
    if args.out:
        with output_set():  # the table, measure.json and the overlays, or none of them
            written = _write_set(args, results, locs, reports, table, loc)
    summ = table.summary()
    for w in warned:  # only once every input is read: a bad input still prints one line
        print(w, file=sys.stderr)
    print("\n".join(lines))
    print(f"measure: {_count(summ['count'])}, median s = {summ['s_median_um']:.4g} µm, median r = {summ['r_median']:.3f}"
          + (f"; wrote {path_text(args.out)}, {path_text(Path(args.out).parent / 'measure.json')}"
             + (f" and {len(written)} overlay(s)" if written else "") if args.out else ""))
    return 0


def _write_set(args, results, locs, reports, table, loc) -> list[str]:
    """Write the overlays, ``measure.json`` and the table (call inside :func:`bmctl.io.output_set`).

    Parameters
    ----------
    args : argparse.Namespace
        The command line (``--out``, ``--no-overlay``, the inputs).
    results : list of MicrographResult
        The measured images, in the order of the image inputs.
    locs : list of ParticleLocations
        Per input (tables and images), the particles' ids.
    reports : list of dict
        Per input, its ``measure.json`` entry (an image's gets its overlay's path).
    table : ParticleTable
        All particles.
    loc : ParticleLocations
        All particles' ids, images and centroids.

    Returns
    -------
    list of str
        The overlays written.
    """
    from ..io import write_text
    from ..measure.names import path_text
    from ..measure.overlay import write_overlay
    from ..measure.tables import write_table

    folder, written = Path(args.out).parent, []
    if not args.no_overlay:
        img_index = [i for i, p in enumerate(args.inputs) if not _is_table(p)]
        for res, out_png, i in zip(results, _overlay_names([res.name for res in results], folder), img_index):
            write_overlay(out_png, res.image, res.segmentation.labels, res.segmentation.offset, locs[i].particle_id,
                          excluded_from_row=res.info_bar_row, excluded_to_row=res.info_bar_top_last_row, scale_bar=res.scale_bar,
                          crop=getattr(args, "crop", None),
                          title=f"{path_text(Path(res.name).name)}: {_count(len(res.table))}, {res.scale.um_per_px:.4g} µm/px, "
                                f"{res.segmentation.polarity} particles, verdict {res.verdict}")
            reports[i]["overlay"] = str(out_png)
            written.append(str(out_png))
    summ = table.summary()
    doc = {"table": str(args.out), "count": summ["count"], "s_median_um": summ["s_median_um"],
           "r_median": summ["r_median"], "inputs": reports}
    write_text(folder / "measure.json", json.dumps(_finite(doc), indent=2, allow_nan=False) + "\n")
    write_table(args.out, table, loc)
    return written
