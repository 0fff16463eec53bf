"""Linear analysis of the moment model (python-control): ranks, gramians, step responses."""

from __future__ import annotations

from ..errors import InputError
from ..naming import naming
from ._args import LIBRARY_FLAGS, hours_arg, output_path, rpm_arg
from ._model import add_identify_flag


def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card (its identified moment model is used if present)")
    p.add_argument("--rpm", type=rpm_arg("--rpm"), default=None, help="operating speed (default: the card's)")
    p.add_argument("--at-hours", type=hours_arg("--at-hours", zero=True), default=6.0,
                   help="linearise at the state reached after this many hours at --rpm (default 6)")
    p.add_argument("--horizon", type=hours_arg("--horizon"), default=2.0, help="gramian horizon in h (default 2)")
    p.add_argument("--out", default="out/linearize", metavar="DIR", help="output folder (default out/linearize)")
    add_identify_flag(p)


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    import numpy as np

    from ..config import load_card
    from ..io import name_part, savefig
    from ._model import model_for, warn_window
    from ..moments.linear import analyse, operating_point, step_figure

    card = load_card(args.model)
    rpm = card.process.rpm if args.rpm is None else args.rpm
    if rpm <= 0 or rpm > card.mill.rpm_max:
        src = "--rpm" if args.rpm is not None else f"{args.model}: process.rpm (give --rpm)"
        raise InputError(f"{src}: must be in (0, {card.mill.rpm_max:g}] (got {rpm:g})")
    if args.horizon <= 0:
        raise InputError(f"--horizon: must be > 0 (got {args.horizon:g})")
    from ..work import check_work, moment_work

    check_work(moment_work(args.at_hours + args.horizon), "--at-hours/--horizon")
    out = output_path(args.out)
    model = model_for(args.model, args.identify)
    warn_window(model, [rpm])
    x, u = operating_point(model, rpm, args.at_hours)
    a = analyse(model, x, u, horizon_h=args.horizon)
    names = model.state_names
    print(f"{card.card.name}: moment model ({model.coeffs_source}) linearised at rpm {rpm:g}, "
          f"milling 1, after {args.at_hours:g} h")
    print("  x = " + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, x)))
    ev = np.sort_complex(a["eig"])
    print("  eigenvalues (1/h): " + ", ".join(f"{z.real:.3g}" + (f"{z.imag:+.3g}j" if abs(z.imag) > 1e-9 else "")
                                             for z in ev))
    print(f"  controllability rank from (rpm, milling): {a['ctrb_rank']}/6   "
          f"(rpm alone {a['ctrb_rank_rpm']}, milling alone {a['ctrb_rank_milling']})")
    print(f"  observability rank from (s_mean, s_std, r_mean, r_std): {a['obsv_rank']}/6   "
          f"(size moments alone {a['obsv_rank_no_r']})")
    print(f"  gramian condition numbers over {args.horizon:g} h (scaled units): "
          f"controllability {a['gram_c_cond']:.3g}, observability {a['gram_o_cond']:.3g}")
    fig = step_figure(model, x, u)
    path = out / f"{name_part(card.card.name)}-step-rpm{rpm:g}-at{args.at_hours:g}h.png"
    savefig(fig, path, dpi=110)
    print(f"  wrote {path}")
    return 0
