"""Design an open-loop rpm/rest schedule that reaches a moment target (the MPC problem over a whole batch)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ._args import hours_arg, output_path
from ._model import add_identify_flag, heldout_text, model_for, warn_window

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CONTROLLER = "controllers/mpc-default.toml"


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
    add_identify_flag(p)


def _controller_path(arg) -> Path:
    if arg is not None:
        return Path(arg)
    local = Path(DEFAULT_CONTROLLER)
    return local if local.exists() else ROOT / DEFAULT_CONTROLLER


def run(args) -> int:
    from ..control.config import MPCConfig, load_controller, parse_target
    from ..control.design import design_schedule, write_design

    # all input checks first: nothing is written on bad input
    target = parse_target(args.target)
    path = _controller_path(args.controller)
    cfg = load_controller(path)
    if not isinstance(cfg, MPCConfig):
        raise InputError(f"{path}: kind: design needs an mpc controller (got {cfg.kind!r})")
    out = output_path(args.out)
    model = model_for(args.model, args.identify)
    hours = args.hours if args.hours is not None else float(model.card.process.hours)
    from ..cards import check_work, design_work

    check_work(design_work(hours, cfg.interval_h), f"--hours/{path}: interval_h")

    d = design_schedule(model, target, hours, cfg, objective=args.objective)
    if not d.reach.reachable:  # said up front, before the schedule; exit status stays 0
        print(f"warning: {d.reach.line(target)}")
    paths = write_design(d, out)
    from ..control.config import format_target

    r = d.result
    got = ", ".join(f"{k} {r.outputs[k]:.4g} (target {format_target(v)})" for k, v in target.items())
    n = len(d.segments)
    print(f"{d.card_name}: {d.hours:g} h ({d.objective}), {n} segment{'s' if n != 1 else ''}, {r.switches} switches, "
          f"{d.milling_h:.2f} h milling, {d.energy_kWh:.3f} kWh; predicted {got}; peak T {r.peak_c:.1f} °C "
          f"(ceiling {d.ceiling_c:g} °C); {r.method} {r.status}, {r.solve_s:.1f} s")
    print(f"  prediction's moment model: {heldout_text(model)} ({model.coeffs_source})")
    warn_window(model, [rpm for _, rpm in d.segments])
    if d.pareto:
        from ..control.design import pareto_table

        print(pareto_table(d))
    for p_ in paths:
        print(f"  wrote {p_}")
    return 0
