"""Segment micrographs into per-particle size s and aspect ratio r (and pass particle tables through).

Each IMAGE is segmented (:func:`bmctl.measure.segment.segment`) and its particles measured
in micrometres; a ``.csv`` argument is read as a particle table instead
(:func:`bmctl.measure.tables.read_table`) and normalised. All inputs are pooled into one
table ``area_um2,perimeter_um,s_um,r`` written atomically to ``--out``; nothing is written
when any input is bad.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError
from ._args import output_path

#: default --min-area-px; equals bmctl.measure.segment.MIN_AREA_PX (a test checks), kept here so that
#: building the parser does not import the image stack
MIN_AREA_PX = 30


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``measure`` arguments."""
    parser.add_argument("inputs", nargs="+", metavar="IMAGE", help="micrograph(s) (png/tif/...) or particle table(s) (.csv)")
    parser.add_argument("--um-per-px", type=float, default=None, metavar="X", help="pixel size in micrometres (required for images)")
    parser.add_argument("--out", default=None, metavar="CSV", help="write the pooled particle table here")
    parser.add_argument("--min-area-px", type=int, default=MIN_AREA_PX, metavar="N", help=f"drop blobs below N px (default {MIN_AREA_PX})")
    parser.add_argument("--crop", default=None, metavar="Y0:Y1,X0:X1", help="keep this window, e.g. 0:423,: to cut an info bar")
    parser.add_argument("--dark-particles", action="store_true", help="particles darker than the background")
    parser.add_argument("--no-flatten", action="store_true", help="skip the background flattening")


def _is_table(path: str) -> bool:
    return Path(path).suffix.lower() == ".csv"


def run(args: argparse.Namespace) -> int:
    """Measure all inputs, print a summary, write ``--out``; bad input raises InputError."""
    from ..measure.segment import check_scale, measure_labels, parse_crop, segment
    from ..measure.tables import ParticleTable, read_table, write_table

    scale = check_scale(args.um_per_px) if args.um_per_px is not None else None
    if args.min_area_px < 1:
        raise InputError(f"--min-area-px: must be >= 1 (got {args.min_area_px})")
    crop = parse_crop(args.crop) if args.crop is not None else None
    if args.out:
        output_path(args.out, folder=False)
    images = [p for p in args.inputs if not _is_table(p)]
    if images and scale is None:
        raise InputError(f"--um-per-px: required to measure images ({images[0]})")
    tables, lines = [], []
    for path in args.inputs:
        if _is_table(path):
            t = read_table(path)
        else:
            seg = segment(path, min_area_px=args.min_area_px, crop=crop, flatten=not args.no_flatten,
                          dark_particles=args.dark_particles)
            t = measure_labels(seg.labels, scale)
        tables.append(t)
        lines.append(f"{path}: {len(t)} particles")
    table = ParticleTable.concat(tables)
    if len(table) == 0:
        raise InputError(f"{args.inputs[0]}: no particles found (check --um-per-px, --min-area-px, --crop)")
    if args.out:
        write_table(args.out, table)
    summ = table.summary()
    print("\n".join(lines))
    print(f"measure: {summ['count']} particles, median s = {summ['s_median_um']:.4g} um, median r = {summ['r_median']:.3f}"
          + (f"; wrote {args.out}" if args.out else ""))
    return 0
