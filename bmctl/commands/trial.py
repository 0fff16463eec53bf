"""Closed-loop trial: stochastic plant, micrograph sampling, particle filter and controller."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ..naming import naming
from ._args import LIBRARY_FLAGS, int_arg, output_path, progress_bar
from ._model import add_identify_flag, model_for, warn_window




def configure(p):
    p.add_argument("scenario", metavar="SCENARIO.toml", help="trial definition (see scenarios/trial-*.toml)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="random seed (default 0)")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default out/trial-<name>-seed<N>)")
    p.add_argument("--resume", default=None, metavar="DIR", help="carry on an interrupted trial in DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--campaign", action="store_true",
                   help="run the trial through the campaign verbs (the plant as the person at the mill); "
                        "leaves DIR/campaign/ for `bmctl campaign status/report` (no --resume)")
    add_identify_flag(p)


#: CPU seconds of one filter particle per sample and of one feedback solve (docs/estimation.md, docs/control.md)
FILTER_CPU_S_PER_PARTICLE = 2e-4
SOLVE_CPU_S = 2.0


def _check_trial_work(sc, path):
    """Refuse a trial whose plant, filter and controller work exceeds the budget; returns the plant's card."""
    from ..cards import check_work, simulation_work
    from ..config import load_card, with_factors
    from ..control.config import load_controller
    from ..scenario import resolve
    from ..work import add, filter_work

    base = Path(path).resolve().parent
    card = load_card(resolve(sc.plant.model or sc.model, base))
    with_factors(card, sc.plant.gamma_factor, sc.plant.delta_factor, source=f"{path}: plant")  # a card it allows
    from ..trial import check_resolvable

    check_resolvable(sc, path, card)  # a pixel size at which no sample can be taken: said as such
    cfg = load_controller(resolve(sc.controller.config, base))
    work = simulation_work(card, [(sc.hours, card.mill.rpm_max)], sc.plant.particles, sc.sampling.every_h, raster=False)
    samples = sc.hours / sc.sampling.every_h + 1
    work["cpu_s"] += samples * sc.estimator.particles * FILTER_CPU_S_PER_PARTICLE
    work = add(work, filter_work(sc.hours, sc.estimator.particles))  # the filter's propagation between samples
    # each sample renders and segments whole micrographs (the starting powder's field), counted at measure's
    # cost per pixel: above the rendered samples' own (0.1-0.4 of it on the lab card at 0.5-2 µm/px)
    if sc.sampling.render:
        from ..measure.sampler import render_field
        from ..trial import initial_sizes
        from ..work import MEASURE_CPU_S_PER_PX, MEASURE_PEAK_BYTES_PER_PX

        _, side, per_image = render_field(initial_sizes(card), sc.sampling.um_per_px)
        images = -(-sc.sampling.particles // per_image)
        work["cpu_s"] += samples * images * side * side * MEASURE_CPU_S_PER_PX
        work["memory_bytes"] = max(work["memory_bytes"], side * side * MEASURE_PEAK_BYTES_PER_PX)
    if cfg.kind != "recipe":
        work["cpu_s"] += SOLVE_CPU_S * sc.hours / (getattr(cfg, "interval_h", None) or 0.5)
    check_work(work, f"{path}: hours/plant.particles/sampling.every_h/estimator.particles"
                     + ("/sampling.render/sampling.um_per_px" if sc.sampling.render else ""))
    return card


#: the library's arguments as this command's flags (a resumed trial's folder is --resume's; the
#: library names the folder as out only when it starts one)
TRIAL_FLAGS = {**LIBRARY_FLAGS, "resume=True": "--resume", "seed": "--seed", "out": "--out"}


@naming(TRIAL_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    from ..io import name_part
    from ..scenario import load_scenario
    from ..trial import run_trial

    sc = load_scenario(args.scenario, campaign=args.campaign)  # every input check before --out is touched
    if args.campaign and args.resume:
        raise InputError("--resume: a trial run with --campaign does not resume (the simulated plant is not in the "
                         "campaign); run it again with the same --seed into a new --out: same trajectory")
    if args.resume and args.out and Path(args.resume) != Path(args.out):
        raise InputError("--resume: give the trial folder once (--resume DIR), not with a different --out")
    out = output_path(args.resume or args.out or f"out/trial-{name_part(sc.scenario.name)}-seed{args.seed}",
                      "--resume" if args.resume else "--out")
    card = _check_trial_work(sc, args.scenario)
    from ..scenario import resolve

    model = model_for(resolve(sc.model, Path(args.scenario).resolve().parent), args.identify)
    bar = None
    if not args.no_progress:
        bar = progress_bar(total=None, unit="step", desc=sc.scenario.name)

    def progress(k, K):
        if bar is not None:
            bar.total = K
            bar.update(k - bar.n)
    try:
        if args.campaign:
            from ..campaign.simulated import run_trial_as_campaign

            summary = run_trial_as_campaign(args.scenario, out, seed=args.seed, progress=progress)
        else:
            summary = run_trial(args.scenario, out, seed=args.seed, resume=args.resume is not None,
                                progress=progress)
    finally:
        if bar is not None:
            bar.close()
    from ..cards import validity

    t_max = validity(card)["temperature_max_C"]
    if t_max is not None and summary["max_temperature_c"] > t_max:
        print(f"bmctl: warning: {card.card.name}: vial temperature {summary['max_temperature_c']:.0f} °C is above the "
              f"card's maximum {t_max:g} °C ({validity(card)['temperature_reason']}): the model does not hold there",
              file=sys.stderr)
    warn_window(model, _milling_rpms(out / "trajectory.csv"))
    err = ", ".join(f"{k} {v:.1%}" for k, v in summary["final_error"].items()) or "(no target)"
    print(f"{sc.scenario.name} seed {args.seed}: final error {err}; max T {summary['max_temperature_c']:.1f} °C, "
          f"{summary['temperature_violations']} violations; energy {summary['energy_kj']:.0f} kJ; "
          f"{summary['fallbacks']} fallbacks; median solve {summary['median_solve_ms']:.0f} ms")
    from ..control.config import Objective

    tol = Objective.model_fields["tolerance"].default  # a miss: beyond the controllers' default tolerance
    missed = [k for k, v in summary["final_error"].items() if abs(v) > tol]
    if missed:  # always said; why, as the plans saw it, where they recorded binding limits
        first, last = summary.get("binding_first") or [], summary.get("binding_last") or []
        print(f"  missed by more than {tol:.0%} ({', '.join(missed)})"
              + (f"; binding limits of the first plan: {'; '.join(first) or 'none'}; of the last: "
                 f"{'; '.join(last) or 'none'}" if first or last else ""))
    law = {k: v for k, v in (summary.get("final_true_law") or {}).items() if k in summary["target"]}
    if law:  # the controller steers the size law's D-values; the powder's own can differ (docs/fidelity.md)
        print("  D-values of the plant's particles " + ", ".join(f"{k} {summary['final_true'][k]:.2f}" for k in law)
              + "; through the size law of their mean and std (what the controller steers) "
              + ", ".join(f"{k} {v:.2f}" for k, v in law.items()))
    print(f"  wrote {out}/trajectory.csv, summary.json, trial.json, trial.png"
          + ("" if args.campaign else ", checkpoint.npz")
          + (f"; the campaign in {out}/campaign (bmctl campaign report {out}/campaign)" if args.campaign else ""))
    return 0


def _milling_rpms(path: Path) -> set[float]:
    """The speeds a trial milled at (its trajectory.csv's rpm where milling > 0)."""
    import csv

    with open(path, newline="", encoding="utf-8") as f:
        return {float(r["rpm"]) for r in csv.DictReader(f) if float(r["milling"]) > 0 and float(r["rpm"]) > 0}
