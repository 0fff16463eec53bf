"""Compare a measured particle sample with the plant's predicted size and irregularity at a time.

The stochastic plant runs the card's recipe (or ``--schedule``) for ``--at-h`` hours from
``--seed``; the measured table (``bmctl measure`` output, or any ``area_um2,perimeter_um`` /
``s_um,r`` table) is compared with the predicted population by Kolmogorov-Smirnov and
Anderson-Darling two-sample tests on s and on r. Writes ``compare.png`` (histograms, log size
axis) and ``compare.json`` into ``--out``.
"""

from __future__ import annotations

import json
import sys

from ..naming import naming
from ._args import LIBRARY_FLAGS, hours_arg, int_arg, output_path


def configure(p):
    """Add the ``compare`` arguments."""
    p.add_argument("sample", metavar="SAMPLE.csv", help="measured particle table")
    p.add_argument("--model", required=True, metavar="CARD.toml", help="model card")
    p.add_argument("--schedule", default=None, metavar="S.toml", help="[[segment]] hours, rpm (default: the card's recipe)")
    p.add_argument("--at-h", type=hours_arg("--at-h", zero=True), required=True, metavar="T", help="milling time of the sample (h)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="plant seed (default 0)")
    p.add_argument("--particles", type=int_arg("--particles", 100, 10_000_000), default=None, metavar="M", help="simulated particles")
    p.add_argument("--out", default="out/compare", metavar="DIR", help="output folder (default out/compare)")


def _ad_p_text(p: float) -> str:
    """scipy floors the Anderson-Darling p-value at 0.001 and caps it at 0.25: at either end the
    true value is beyond it, which the printed line says."""
    if p <= 0.001 * (1 + 1e-9):
        return "p ≤ 0.001, scipy's floor"
    if p >= 0.25 * (1 - 1e-9):
        return "p ≥ 0.25, scipy's cap"
    return f"p = {p:.3g}"


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    """Simulate to ``--at-h``, compare, print the statistics, write the figure and JSON."""
    import numpy as np

    from ..config import load_card
    from ..io import output_set, write_text
    from ..measure.compare import compare_figure, predicted_population, two_sample
    from ..measure.names import path_text
    from ..schedule import Schedule
    from ..measure.tables import read_table

    from pathlib import Path

    from ..errors import InputError
    from .estimate import IMAGE_SUFFIXES

    if Path(args.sample).suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(f"{args.sample}: a micrograph, not a particle table (.csv); measure it first "
                         "(bmctl measure IMAGE --out TABLE.csv) and compare the table")
    table = read_table(args.sample)
    if len(table) < 2:  # the two-sample tests need two values a side: say so before the plant runs
        raise InputError(f"{args.sample}: need at least 2 particles (got {len(table)})")
    card = load_card(args.model)
    if args.schedule is not None:
        sched = Schedule.load(args.schedule)
        sched.check_rpm_max(card.mill.rpm_max, args.schedule)  # as whatif: the file and segment, before any work
        segments = sched.pairs()
    else:
        segments = Schedule.from_card(card).pairs()
    from ..cards import check_melting, simulation_work
    from ..measure.compare import truncate_schedule
    from ..work import check_work

    ran = truncate_schedule(segments, args.at_h)  # what the plant runs: the schedule cut at --at-h
    # the vial's peak over what runs, as simulate and whatif: above the melting limit nothing runs
    check_melting(card, ran, args.schedule or f"{args.model}: process.rpm")
    check_work(simulation_work(card, ran or [(1e-3, 0.0)],
                               args.particles or card.simulation.particles, max(args.at_h, 1e-3), raster=False),
               "--at-h/--particles/--schedule")
    out = output_path(args.out)
    rng = np.random.default_rng(args.seed)
    s_pred, r_pred = predicted_population(card, segments, args.at_h, rng, args.particles)
    s_stat, r_stat = two_sample(table.s_um, s_pred), two_sample(table.r, r_pred)
    doc = {"sample": args.sample, "model": args.model, "schedule": args.schedule, "at_h": args.at_h,
           "seed": args.seed, "n_measured": len(table), "m_predicted": int(s_pred.size),
           "s_um": s_stat.as_dict(), "r": r_stat.as_dict()}
    with output_set():  # the figure and the JSON, or neither
        compare_figure(out / "compare.png", table.s_um, table.r, s_pred, r_pred,
                       title=f"{path_text(args.sample)} vs {path_text(args.model)} at {args.at_h:g} h (seed {args.seed})")
        write_text(out / "compare.json", json.dumps(doc, indent=2) + "\n")
    for name, st, unit in (("s", s_stat, " µm"), ("r", r_stat, "")):
        print(f"{name}: median measured {st.median_measured:.4g}{unit}, predicted {st.median_predicted:.4g}{unit}; "
              f"KS D = {st.ks:.3f} (p = {st.ks_p:.3g}), Anderson-Darling A = {st.ad:.2f} ({_ad_p_text(st.ad_p)})")
    if r_stat.ks_p < R_NOTE_P and r_stat.median_measured > r_stat.median_predicted:
        print(r_note(r_stat.median_measured, r_stat.median_predicted))
    print(f"compare: wrote {path_text(out / 'compare.png')}, {path_text(out / 'compare.json')}")
    for line in validity_warnings(card, ran, args.at_h, float(np.mean(s_pred))):
        print(f"bmctl: warning: {line}", file=sys.stderr)
    return 0


def validity_warnings(card, segments, at_h: float, s_mean_um: float) -> list[str]:
    """The warnings ``simulate`` gives (:func:`bmctl.cards.simulation_warnings`) for the run a comparison
    makes (one line each): the vial above the card's maximum (at its exact peak,
    :func:`bmctl.cards.peak_temperature_c`), the predicted mean size outside the card's range at ``at_h``,
    and a milling speed outside the calibrated window.

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm)
        The schedule as run, cut at ``at_h``.
    at_h : float
        The sample's time (h).
    s_mean_um : float
        The predicted population's mean size there (µm).

    Returns
    -------
    list of str

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> validity_warnings(card, [(2.0, 300.0)], 2.0, 45.0)
    []
    >>> print(validity_warnings(card, [(3.0, 600.0)], 3.0, 15.0)[0][:63])
    alni-1to1-300rpm-lab: steady vial temperature 349 °C at 600 rpm
    """
    from ..cards import peak_temperature_c, simulation_warnings

    peak, at = peak_temperature_c(card, segments)
    # the peak and the final size are the run's records here, each at its own time
    return simulation_warnings(card, segments, [at], [peak], [s_mean_um], size_t_h=[at_h])


#: below this KS p-value a measured r above the prediction gets :func:`r_note`
R_NOTE_P = 0.001


def r_note(measured: float, predicted: float) -> str:
    """Why a micrograph's r above the plant's is not by itself a model miss (docs/measurement.md, Sec. 8.3).

    Examples
    --------
    >>> print(r_note(0.014, 7e-5))  # doctest: +NORMALIZE_WHITESPACE
    note: r: the prediction carries no measurement noise, and a micrograph reads round particles a
    little irregular (median r 0.014 measured, 7e-05 predicted): a rejected r is not by itself a
    model miss (docs/measurement.md, Sec. 8.3)
    """
    return (f"note: r: the prediction carries no measurement noise, and a micrograph reads round particles a little "
            f"irregular (median r {measured:.2g} measured, {predicted:.2g} predicted): a rejected r is not by itself "
            "a model miss (docs/measurement.md, Sec. 8.3)")
