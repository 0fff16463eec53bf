"""Design an open-loop rpm/rest schedule that reaches a moment target (the MPC problem over a whole batch)."""

from __future__ import annotations

import sys

from ..errors import InputError
from ..naming import naming
from ._args import DEFAULT_CONTROLLER, LIBRARY_FLAGS, controller_path, hours_arg, int_arg, output_path
from ._model import add_identify_flag, heldout_text, model_for, warn_window


def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card (see models/)")
    p.add_argument("--target", required=True, metavar="K=V,...",
                   help="target at the batch end, e.g. s_mean_um=25,r_mean=0.05 or a window d50_um=40:50 "
                        "(keys: s_mean_um, s_std_um, r_mean, r_std, d50_um, d90_um, span)")
    p.add_argument("--objective", choices=("target", "min_time", "min_energy"), default=None,
                   help="target: error + energy/time weights; min_time / min_energy: shortest or cheapest batch "
                        "within the tolerance (default: the controller's [objective] kind)")
    p.add_argument("--hours", type=hours_arg("--hours"), default=None, help="batch length in h (default: the card's)")
    p.add_argument("--controller", default=None, metavar="FILE.toml",
                   help=f"MPC controller file (default {DEFAULT_CONTROLLER})")
    p.add_argument("--out", default="out/design", metavar="DIR", help="output folder (default out/design)")
    p.add_argument("--plant-seeds", type=int_arg("--plant-seeds", 0, 64), default=3, metavar="N",
                   help="plants the designed schedule is checked on (seeded ensemble; 0: no check; default 3)")
    p.add_argument("--plant-particles", type=int_arg("--plant-particles", 100, 1_000_000), default=None,
                   metavar="N", help="simulated particles per plant of the check (default 5000)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=None, help="seed of the plant check (default 0)")
    p.add_argument("--workers", type=int_arg("--workers", 0, 256), default=None,
                   help="Dask workers of the plant check (default: serial for a small ensemble; at most one per "
                        "plant and 4 per CPU)")
    add_identify_flag(p)


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    from ..control.config import MPCConfig, check_ceiling, load_controller, parse_target
    from ..control.design import (check_batch, design_schedule, done_text, mill_violations, switches_of, switches_text,
                                  write_design)

    # all input checks first: nothing is written on bad input
    if args.plant_seeds == 0:  # flags of the plant check, which --plant-seeds 0 skips: they would do nothing
        given = [f for f, v in (("--seed", args.seed), ("--workers", args.workers),
                                ("--plant-particles", args.plant_particles)) if v is not None]
        if given:
            raise InputError(f"{given[0]}: sets the plant check, which --plant-seeds 0 skips")
    args.seed = 0 if args.seed is None else args.seed
    args.plant_particles = 5000 if args.plant_particles is None else args.plant_particles
    target = parse_target(args.target)
    path = controller_path(args.controller)
    cfg = load_controller(path)
    if not isinstance(cfg, MPCConfig):
        raise InputError(f"{path}: kind: design needs an mpc controller (got {cfg.kind!r})")
    out = output_path(args.out)
    model = model_for(args.model, args.identify)
    hours = args.hours if args.hours is not None else float(model.card.process.hours)
    hours_source = "--hours" if args.hours is not None else f"{args.model}: process.hours (the default of --hours)"
    check_batch(hours, cfg, args.objective, hours_source, str(path))
    check_ceiling(cfg, model.card, str(path))
    from ..control.base import check_rpm_range

    check_rpm_range(cfg, model.rpm_max)  # no speed left to mill at: refused here, before any progress line
    from ..cards import check_work, design_work

    swept = (args.objective or cfg.objective.kind) != "target"  # min_time / min_energy design every batch of the sweep
    work = design_work(hours, cfg.interval_h, cfg.objective.sweep if swept else (1.0,))
    if args.plant_seeds:  # the plant check, at the top speed throughout (an upper bound)
        from ..cards import simulation_work
        from ..work import add, scale

        top = min(cfg.bounds.rpm_max, model.rpm_max)
        plant = scale(simulation_work(model.card, [(hours, top)], args.plant_particles, 0.05, raster=False),
                      args.plant_seeds)
        if plant["memory_bytes"] <= work["memory_bytes"]:  # the memory is the search's, not recorded populations
            plant.pop("records", None)
        work = add(work, plant)
    check_work(work, f"--hours/--plant-seeds/--plant-particles/{path}: interval_h" + (", objective.sweep" if swept else ""))

    def progress(text):
        print(f"design: {text}", file=sys.stderr, flush=True)

    d = design_schedule(model, target, hours, cfg, objective=args.objective, progress=progress)
    broken = mill_violations(d, cfg.mill)
    if broken:  # a schedule the mill cannot run is not written (the search's families assume intervals of minutes)
        raise InputError(f"{path}: the designed schedule breaks the mill's limits ({'; '.join(broken[:3])}); nothing "
                         f"written: lengthen interval_h ({cfg.interval_h:g} h) or relax [mill]")
    from ..control.config import format_target

    if not d.reach.reachable:  # said up front, before the schedule; exit status stays 0
        print(f"warning: {d.reach.line(target)}")
        print("best schedule per family of the global search (moment model):")
        print("\n".join(d.family_lines()))
    if args.plant_seeds:
        from ..control.design import plant_check

        progress(f"checking the schedule on {args.plant_seeds} plant{'s' if args.plant_seeds != 1 else ''} of "
                 f"{args.plant_particles} particles")
        d.plant = plant_check(model.card, d.segments, target, args.plant_seeds, args.plant_particles, args.seed,
                              args.workers)
    paths = write_design(d, out)
    r = d.result
    got = ", ".join(f"{k} {r.outputs[k]:.4g} (target {format_target(v)})" for k, v in target.items())
    n = len(d.segments)
    print(f"{d.card_name}: {d.hours:g} h ({d.objective}), {n} segment{'s' if n != 1 else ''}, "
          f"{switches_text(d.switches)}, "
          f"{d.milling_h:.2f} h milling, {d.energy_kWh:.3f} kWh; predicted {got}; peak T {r.peak_c:.1f} °C "
          f"(ceiling {d.ceiling_c:g} °C); {r.method} ({r.status}), {r.solve_s:.1f} s")
    done = done_text(d)
    if done:  # a trailing rest is not written; the sweep's grid is coarser than the milling
        print(f"  {done}")
    if d.local is not None and d.local is not r:
        print(f"  local NLP (from the search's best schedules): error {100 * d.local.error:.2f} %, "
              f"{switches_text(switches_of(d.local))}, peak T {d.local.peak_c:.1f} °C: not better")
    elif d.local is not None:  # the search's schedule as written, integrated as the summary's
        print(f"  global search's best: error {100 * d.searched.error:.2f} %; the local NLP improved on it")
    if args.plant_seeds:
        pc = d.plant
        tol = cfg.objective.tolerance
        parts, off = [], []
        from ..control.outputs import relative_error

        for k, v in target.items():
            m = pc[k]["mean"]
            law = pc[k].get("law_mean")
            parts.append(f"{k} {m:.4g} [{pc[k]['min']:.4g}, {pc[k]['max']:.4g}] (moment model {r.outputs[k]:.4g}"
                         + (f"; size law of the plants' mean and std {law:.4g}" if law is not None else "") + ")")
            dev = abs(m - r.outputs[k]) / max(abs(r.outputs[k]), 1e-12)
            if dev > tol:
                off.append(f"{k} {100 * dev:.1f} %" + (
                    "" if law is None else f" (the model against the size law of the plants' mean and std "
                    f"{100 * abs(law - r.outputs[k]) / max(abs(r.outputs[k]), 1e-12):.1f} %, that law against the "
                    f"plants' particles {100 * abs(m - law) / max(abs(law), 1e-12):.1f} %: docs/fidelity.md)"))
        print(f"plant check ({pc['seeds']} plant{'s' if pc['seeds'] != 1 else ''}, seed {args.seed}): "
              + "; ".join(parts)
              + f"; peak T {pc['temperature_peak_c']:.1f} °C")
        if off:
            print(f"warning: the plant and the moment model disagree by more than the tolerance "
                  f"({100 * tol:g} %): {', '.join(off)}")
    print(f"  prediction's moment model: {heldout_text(model)} ({model.coeffs_source})")
    warn_window(model, [rpm for _, rpm in d.segments])
    if d.pareto:
        from ..control.design import pareto_table

        print(pareto_table(d))
    for p_ in paths:
        print(f"  wrote {p_}")
    return 0
