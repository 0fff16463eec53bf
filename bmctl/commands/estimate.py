"""Estimates of the powder's moments and rate multipliers from micrograph samples (particle filter or UKF).

``bmctl estimate MODEL.toml --samples DIR_OR_FILES --times T1,T2,...`` reads one particle
table (CSV ``area_um2,perimeter_um`` or ``s_um,r``; or a micrograph with ``--um-per-px``) per
sample time, runs the moment model between samples under the card's recipe (or
``--schedule``/``--rpm``), and writes ``estimate.csv`` (t_h, ESS and the mean and 90 %
interval of every state and parameter at each sample time) and a figure next to it
(``<name>.png``); ``--write-card OUT.toml`` also writes the card with the estimated gamma, delta
(an existing OUT.toml only with ``--force``). Bad input: one line, exit 2, nothing written. See
docs/estimation.md.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from ..errors import InputError, finite_float
from ..naming import naming
from ._args import LIBRARY_FLAGS, float_arg, int_arg, output_path, progress_bar, rpm_arg
from ._model import add_identify_flag, model_for, warn_window

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")






def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card (see models/); its moment model is the filter's")
    p.add_argument("--samples", nargs="+", required=True, metavar="DIR_OR_FILES",
                   help="particle tables (.csv) or micrographs (with --um-per-px), one per time; a folder is read sorted by name")
    p.add_argument("--times", required=True, metavar="T1,T2,...", help="milling time (h) of each sample, comma separated")
    p.add_argument("--schedule", default=None, metavar="FILE.toml", help="[[segment]] hours, rpm (rpm 0 = rest); default: the card's recipe")
    p.add_argument("--rpm", type=rpm_arg("--rpm"), default=None, help="sun-disc speed of the card's recipe (default: the card's)")
    p.add_argument("--temperatures", default=None, metavar="T1,T2,...",
                   help="vial-temperature readings (°C) per sample, comma separated; leave an entry empty for none")
    p.add_argument("--um-per-px", type=float_arg("--um-per-px", lo=0.0, strict=True), default=None, metavar="X",
                   help="pixel size: measure micrographs instead of reading tables")
    p.add_argument("--accept-unusable", action="store_true",
                   help="use micrographs whose measurement verdict is unusable (default: refused)")
    p.add_argument("--out", default="out/estimate/estimate.csv", metavar="FILE.csv", help="estimate table (default out/estimate/estimate.csv)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=None,
                   help="random seed of the particle filter (default 0; refused with --estimator ukf, which draws none)")
    p.add_argument("--estimator", choices=("pf", "ukf"), default="pf",
                   help="particle filter (pf, default) or unscented Kalman filter (ukf); see docs/estimation.md")
    p.add_argument("--particles", type=int_arg("--particles", 100, 1_000_000), default=None,
                   help="filter particles N (default 2000; pf only, refused with --estimator ukf)")
    p.add_argument("--size-law", choices=("weibull", "lognormal"), default="weibull",
                   help="law of s given (s_mean, s_std) (default weibull; see docs/estimation.md)")
    p.add_argument("--sigma-r", type=float_arg("--sigma-r", lo=0.005, hi=1.0), default=None,
                   help="r measurement noise (default 0.034, the synthetic micrograph path's)")
    p.add_argument("--sigma-log-s", type=float_arg("--sigma-log-s", lo=0.0, hi=5.0), default=None,
                   help="ln s measurement noise (default 0.015)")
    p.add_argument("--write-card", default=None, metavar="OUT.toml",
                   help="also write the card with gamma, delta set to the last estimate (the next batch's start); "
                        "an existing OUT.toml is refused unless --force")
    p.add_argument("--force", action="store_true", help="let --write-card replace an existing OUT.toml")
    add_identify_flag(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _parse_list(flag: str, text: str, allow_empty: bool = False) -> list[float | None]:
    out: list[float | None] = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            if allow_empty:
                out.append(None)
                continue
            raise InputError(f"{flag}: empty entry in {text!r}")
        out.append(finite_float(item, flag))
    return out


def _number_key(path: Path) -> list:
    """Sort key that reads the digit runs of a file name as numbers (run-2h before run-10h)."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part.lower())
            for part in re.split(r"(\d+)", path.name) if part]


def _sample_files(paths: list[str], images: bool, folders: list | None = None) -> list[Path]:
    """The sample files; ``folders`` collects (folder, its files in name order) for
    :func:`_folder_order_doubts`. A folder's hidden files (``.x.csv``, the ``._x.csv`` macOS leaves on
    other file systems) are not samples."""
    files: list[Path] = []
    suffixes = IMAGE_SUFFIXES if images else (".csv",)
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.iterdir()
                           if f.is_file() and f.suffix.lower() in suffixes and not f.name.startswith("."))
            if not found:
                kind = "micrographs (" + ", ".join(IMAGE_SUFFIXES) + ")" if images else "particle tables (.csv)"
                raise InputError(f"{p}: no {kind} in this folder")
            if folders is not None:
                folders.append((p, len(files), found))
            files.extend(found)
        elif not p.exists():
            raise InputError(f"{p}: no such file or folder")
        else:
            files.append(p)
    return files


def _folder_order_doubts(folders, times) -> list[str]:
    """Warning lines for folders whose name order (the order read) is not the order of the numbers
    in the names (run-10h.csv read before run-2h.csv): the times would go to the wrong files."""
    out = []
    for folder, start, found in folders:
        if sorted(found, key=_number_key) == found:
            continue
        pairs = ", ".join(f"{f.name} at {t:g} h" for f, t in zip(found, times[start:start + len(found)]))
        out.append(f"{folder}: files are read in name order, so the times go to {pairs}; the numbers in the "
                   "names run in another order: if that is not meant, give --samples the files one by one "
                   "in time order")
    return out


def _read_sample(path: Path, um_per_px: float | None, accept_unusable: bool = False):
    """The sample's particle table and warning lines on doubtful images (unusable ones refused)."""
    from ..measure.micrograph import check_verdicts, table_reports
    from ..measure.tables import read_table

    if path.suffix.lower() == ".csv" or um_per_px is None:
        if path.suffix.lower() != ".csv":
            raise InputError(f"{path}: not a particle table (.csv); give --um-per-px to measure micrographs")
        t = read_table(path)
        return t, check_verdicts(table_reports(path), accept_unusable)
    from ..measure.micrograph import measure_micrograph
    from ..measure.tables import check_table

    res = measure_micrograph(str(path), um_per_px=um_per_px)
    if len(res.table) == 0:
        raise InputError(f"{path}: no particles found in the micrograph (check --um-per-px)")
    return check_table(res.table, str(path)), check_verdicts([res.report()], accept_unusable)


def _refuse_twice(files) -> None:
    """Refuse a sample file given twice (its particles would stand for two times), naming both."""
    from ..io import repeated_file

    pair = repeated_file(files)
    if pair is not None:
        g, f = files[pair[0]], files[pair[1]]
        also = "" if str(f) == str(g) else f" (also as {g})"
        raise InputError(f"--samples: {f} is given twice{also}; each time needs its own sample")


def _refuse_output_onto_input(outputs, inputs) -> None:
    """Refuse an output (``--out`` or the figure beside it) that is one of the run's inputs: it would be
    replaced by the results, the input lost.

    Parameters
    ----------
    outputs : list of (flag, path)
        What the run writes, with the flag that names it.
    inputs : list of path-like
        The card, its coefficients, the schedule and the samples.
    """
    from ..io import same_file

    for flag, out in outputs:
        for other in inputs:
            if same_file(out, other):
                also = "" if str(out) == str(other) else f" (as {other})"
                raise InputError(f"{flag}: {out} is an input of this run{also}; writing there would replace it "
                                 "(choose another file name)")


def _check_write_card(path, taken, force: bool = False) -> None:
    """``--write-card``: a ``.toml`` that is none of the run's inputs or outputs (the card it starts
    from, its coefficients, the samples, the table and figure it writes) and, unless ``force``, no
    existing file (any .toml may be a card or a schedule of the user's, so none is replaced unasked)."""
    card = output_path(path, "--write-card", folder=False)
    if card.suffix.lower() != ".toml":
        raise InputError(f"--write-card: expected a .toml file name (got {path})")
    real = os.path.realpath(card)
    for other in taken:
        if os.path.realpath(other) == real:
            raise InputError(f"--write-card: {path} is also {other}, an input or output of this run; choose another "
                             "file name")
    if os.path.lexists(card) and not force:
        raise InputError(f"--write-card: {path} exists; give --force to replace it, or choose another file name")


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    from ..moments.coeffs import coeffs_path
    from ..schedule import Schedule
    from ..estimate.filter import FilterSettings
    from ..estimate.likelihood import LawSettings
    from .. import io
    from ..config import load_card
    from ..estimate.run import Sample, check_reading, check_sample, collapsed, estimate_rows, plot_estimates, run_filter
    from ..estimate.ukf import UKFSettings
    from ..io import write_csv

    if args.particles is not None and args.estimator == "ukf":  # a count the UKF would ignore
        raise InputError("--particles: a particle count, but --estimator ukf has sigma points, no particles")
    if args.seed is not None and args.estimator == "ukf":  # a seed the UKF would ignore
        raise InputError("--seed: seeds the particle filter; --estimator ukf is deterministic and draws no random numbers")
    if args.particles is None:
        args.particles = 2000
    if args.seed is None:
        args.seed = 0
    card = load_card(args.model)
    times = _parse_list("--times", args.times)
    if any(t < 0 for t in times):
        raise InputError(f"--times: must be >= 0 (got {min(times):g})")
    if any(b <= a for a, b in zip(times, times[1:])):  # equal times too: docs/estimation.md, "--times"
        raise InputError(f"--times: must be in increasing order, each later than the one before (got {args.times})")
    if max(times) > 1000.0:  # the longest batch a card allows (bmctl.config.HOURS)
        raise InputError(f"--times: {max(times):g} h exceeds the longest batch, 1000 h")
    folders: list = []
    files = _sample_files(args.samples, images=args.um_per_px is not None, folders=folders)
    if len(files) != len(times):
        raise InputError(f"--times: {len(times)} time(s) for {len(files)} sample(s)")
    temps: list[float | None] = [None] * len(times)
    if args.temperatures is not None:
        temps = _parse_list("--temperatures", args.temperatures, allow_empty=True)
        if len(temps) != len(times):
            raise InputError(f"--temperatures: {len(temps)} reading(s) for {len(times)} sample(s)")
        for temp in temps:
            check_reading(card, temp, "--temperatures")
    if args.um_per_px is not None:
        from ..measure.scale import check_scale

        check_scale(args.um_per_px)
        if all(Path(f).suffix.lower() == ".csv" for f in files):  # a pixel size nothing would use
            raise InputError("--um-per-px: every sample is a particle table (.csv, sizes in µm already); "
                             "it applies to micrographs only")
    if args.rpm is not None and args.rpm > card.mill.rpm_max:
        raise InputError(f"--rpm: {args.rpm:g} exceeds the mill's rpm_max {card.mill.rpm_max:g} ({args.model})")
    t_end = max(times)
    if args.schedule is not None:
        if args.rpm is not None:
            raise InputError("--schedule: cannot be combined with --rpm")
        schedule = Schedule.load(args.schedule)
        schedule.check_rpm_max(card.mill.rpm_max, str(args.schedule))
        segments = schedule.pairs()
        total = sum(h for h, _ in segments)
        if total < t_end - 1e-9:
            raise InputError(f"{args.schedule}: covers {total:g} h, the last sample is at {t_end:g} h")
    else:
        segments = Schedule.from_card(card, max(card.process.hours, t_end), args.rpm).pairs()
    from ..work import check_work, filter_work

    check_work(filter_work(t_end, args.particles if args.estimator == "pf" else 25), "--times/--particles")
    out = output_path(args.out, folder=False)
    if out.suffix.lower() != ".csv":
        raise InputError(f"--out: expected a .csv file name (got {out})")
    _refuse_twice(files)
    inputs = [Path(args.model), coeffs_path(args.model), *files, *([args.schedule] if args.schedule else [])]
    _refuse_output_onto_input([("--out", out), ("--out", out.with_suffix(".png"))], inputs)
    if args.write_card is not None:
        _check_write_card(args.write_card, [out, out.with_suffix(".png"), *inputs], args.force)
    elif args.force:
        raise InputError("--force: only with --write-card (it lets --write-card replace an existing file)")
    law_kw = {"size_law": args.size_law}
    if args.sigma_r is not None:
        law_kw["sigma_r"] = args.sigma_r
    if args.sigma_log_s is not None:
        law_kw["sigma_log_s"] = args.sigma_log_s
    if args.estimator == "ukf":
        settings = UKFSettings(law=LawSettings(**law_kw))
    else:
        settings = FilterSettings(n_particles=args.particles, law=LawSettings(**law_kw))

    samples, warned = [], _folder_order_doubts(folders, times)
    if args.schedule is None and t_end > card.process.hours + 1e-9:  # said, as the other verbs refuse it
        warned.append(f"--times: the last sample ({t_end:g} h) is past the card's {card.process.hours:g} h batch; "
                      f"its process ({args.rpm if args.rpm is not None else card.process.rpm:g} rpm"
                      f"{', --rpm' if args.rpm is not None else ''}) is taken to go on to "
                      f"{t_end:g} h: give --schedule for what the mill ran")
    for f, t, temp in zip(files, times, temps):  # every input is read before the model is built
        tab, doubts = _read_sample(f, args.um_per_px, args.accept_unusable)
        warned += doubts
        samples.append(check_sample(Sample(t, tab.s_um, tab.r, temp, str(f))))
    from ..calibrate.history import size_range_warnings

    warned += size_range_warnings(card, [(s.source, s.t_h, s.s_um) for s in samples])

    for w in warned:
        print(f"bmctl: warning: {w}", file=sys.stderr)
    model = model_for(args.model, args.identify)
    warn_window(model, [rpm for _, rpm in segments])
    bar = progress = None
    if not args.no_progress and t_end * (args.particles if args.estimator == "pf" else 25) > 2000:  # runs > ~2 s
        bar = progress_bar(total=round(t_end, 3), unit="h", desc="filtering",
                   bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} h [{elapsed}<{remaining}]", mininterval=0.5)
        progress = bar.update
    try:
        pf, estimates = run_filter(model, samples, segments, settings, seed=args.seed, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    header, rows = estimate_rows(estimates)
    fig_path = out.with_suffix(".png")
    if args.estimator == "ukf":
        what, health = "unscented Kalman filter", f"covariance repaired {pf.n_repaired}x"
    else:
        what = f"particle filter, N={args.particles}, seed {args.seed}"
        health = f"min ESS {min(e.ess for e in estimates):.0f}, resampled {pf.n_resampled}x"
    with io.output_set():  # the table and its figure, or neither
        write_csv(out, header, rows)
        plot_estimates(fig_path, estimates, samples, title=f"{card.card.name}: {what}")
    for e in estimates:
        if args.estimator == "pf" and collapsed(e):
            print(f"bmctl: warning: {e.t_h:g} h: degenerate update: the effective sample size fell to {e.ess:.2g} of "
                  f"{args.particles}; the 90 % bands at this time are not trustworthy (column 'degenerate' in {out})",
                  file=sys.stderr)
    last = estimates[-1]
    d = last.as_dict()
    print(f"{card.card.name}: {len(samples)} sample{'' if len(samples) == 1 else 's'} to t = {t_end:g} h, {what}; "
          f"{health}")
    print(f"  at {last.t_h:g} h (mean [90 % interval]): s mean {d['s_mean_um']:.1f} µm "
          f"[{d['s_mean_um_q05']:.1f}, {d['s_mean_um_q95']:.1f}], "
          f"r mean {d['r_mean']:.3f} [{d['r_mean_q05']:.3f}, {d['r_mean_q95']:.3f}], "
          f"gamma_mult {d['gamma_mult']:.2f} [{d['gamma_mult_q05']:.2f}, {d['gamma_mult_q95']:.2f}], "
          f"delta_mult {d['delta_mult']:.2f} [{d['delta_mult_q05']:.2f}, {d['delta_mult_q95']:.2f}]")
    print(f"  wrote {out}")
    print(f"  wrote {fig_path}")
    if args.write_card is not None:
        from ..calibrate.writeback import write_estimate_card

        written = write_estimate_card(args.write_card, card, d, f'{len(samples)} samples to {t_end:g} h')
        print(f"  wrote {written} (no moment coefficients of its own yet: `bmctl identify {written}`, about a "
              "minute, or --identify on the command that uses it)")
    return 0
