"""Run the stochastic milling plant on a model card and write moments, populations and figures."""

from __future__ import annotations

import sys

from ..errors import InputError
from ._args import hours_arg, int_arg, output_path, progress_bar, rpm_arg






def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card (see models/)")
    p.add_argument("--hours", type=hours_arg("--hours"), default=None, help="milling time (default: the card's)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="random seed (default 0)")
    p.add_argument("--particles", type=int_arg("--particles", 100, 10_000_000), default=None, help="simulated particles M")
    p.add_argument("--rpm", type=rpm_arg("--rpm"), default=None, help="sun-disc speed (default: the card's)")
    p.add_argument("--schedule", default=None, metavar="FILE.toml", help="[[segment]] hours, rpm (rpm 0 = rest)")
    p.add_argument("--every", type=hours_arg("--every"), default=None, help="recording interval in h (default: the card's simulation.record_every_h)")
    p.add_argument("--out", default="out/simulate", metavar="DIR", help="output folder (default out/simulate)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..config import load_card
    from ..schedule import Schedule
    from ..simulate import simulate, write_outputs

    card = load_card(args.model)
    if args.schedule is not None:
        if args.hours is not None or args.rpm is not None:
            raise InputError("--schedule: cannot be combined with --hours or --rpm")
        schedule = Schedule.load(args.schedule)
        schedule.check_rpm_max(card.mill.rpm_max, str(args.schedule))
        segments = schedule.pairs()
    else:
        if args.hours == 0:
            raise InputError("--hours: must be > 0 (got 0)")
        if args.rpm is not None and args.rpm > card.mill.rpm_max:
            raise InputError(f"--rpm: {args.rpm:g} exceeds the mill's rpm_max {card.mill.rpm_max:g} ({args.model})")
        segments = Schedule.from_card(card, args.hours, args.rpm).pairs()
    if args.every is not None and args.every <= 0:
        raise InputError(f"--every: must be > 0 (got {args.every:g})")
    out = output_path(args.out)
    from ..cards import check_melting, check_work, simulation_warnings, simulation_work

    check_melting(card, segments, args.schedule or ("--rpm" if args.rpm is not None else f"{args.model}: process.rpm"))

    flags = "/".join(f for f, v in (("--hours", args.hours), ("--particles", args.particles), ("--every", args.every),
                                    ("--schedule", args.schedule)) if v is not None) or f"{args.model}: simulation"
    check_work(simulation_work(card, segments, args.particles or card.simulation.particles,
                               args.every or card.simulation.record_every_h), flags)
    total_h = sum(h for h, _ in segments)
    bar = None
    progress = None
    if not args.no_progress and total_h * (args.particles or card.simulation.particles) > 2e5:  # runs > ~1 s
        bar = progress_bar(total=round(total_h, 3), unit="h", desc="milling",
                   bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} h [{elapsed}<{remaining}]", mininterval=0.5)
        progress = bar.update
    try:
        res = simulate(card, segments, seed=args.seed, particles=args.particles, record_every_h=args.every,
                       progress=progress)
    finally:
        if bar is not None:
            bar.close()
    from .. import io

    with io.output_set():  # a late failure leaves none of the run's files
        paths = write_outputs(res, out)
    for line in simulation_warnings(card, segments, res.column("t_h"), res.column("temperature_c"),
                                    res.column("s_mean_um")):
        print(f"bmctl: warning: {line}", file=sys.stderr)
    last = res.records[-1]
    m = last.moments
    print(f"{card.card.name}: {total_h:g} h, M={args.particles or card.simulation.particles}, seed {args.seed}: "
          f"s mean {m['s_mean_um']:.1f} µm, std {m['s_std_um']:.1f} µm, r mean {m['r_mean']:.3f}, "
          f"T {last.temperature_c:.1f} °C")
    for p in paths:
        print(f"  wrote {p}")
    return 0
