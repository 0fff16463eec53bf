"""Compare rpm schedules on an ensemble of the plant: bands of the moments, final pdfs, heat, energy."""

from __future__ import annotations

import sys
from pathlib import Path

from ..naming import naming
from ._args import LIBRARY_FLAGS, int_arg, output_path


def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card")
    p.add_argument("schedules", metavar="SCHEDULE.toml", nargs="+", help="[[segment]] hours, rpm (rpm 0 = rest)")
    p.add_argument("--seeds", type=int_arg("--seeds", 1, 1000), default=5, help="ensemble size (default 5)")
    p.add_argument("--particles", type=int_arg("--particles", 100, 10**7), default=5000,
                   help="simulated particles per plant (default 5000)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="first seed (default 0)")
    p.add_argument("--out", default="out/whatif", metavar="DIR", help="output folder (default out/whatif)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running dask scheduler (tcp://host:8786)")
    p.add_argument("--workers", type=int_arg("--workers", 0, 4096), default=None,
                   help="local Dask worker processes (default: the machine's CPUs for a large ensemble, serial "
                        "for a small one; 0 or 1: serial, no Dask; at most one per seed and 4 per CPU; not with "
                        "--scheduler, whose workers run the plants); same seed, same numbers either way")


@naming(LIBRARY_FLAGS)  # the library's refusals name this command's flags
def run(args) -> int:
    from ..config import load_card
    from ..parallel import check_engine_args
    from ..schedule import Schedule
    from ..whatif import run_schedule_ensemble, table_rows, unique_labels, write_outputs

    check_engine_args(args.workers, args.scheduler)
    out = output_path(args.out)
    card = load_card(args.model)
    scheds = []
    for path in args.schedules:
        sched = Schedule.load(path)
        sched.check_rpm_max(card.mill.rpm_max, path)
        scheds.append((sched.name or Path(path).stem, sched.pairs()))
    # two files may carry one name (two `design` outputs): each label names its schedule alone
    scheds = list(zip(unique_labels([n for n, _ in scheds], args.schedules), (s for _, s in scheds)))
    from ..cards import check_melting, check_work, simulation_warnings, simulation_work

    for (_, segs), path in zip(scheds, args.schedules):
        check_melting(card, segs, path)

    work = [simulation_work(card, segs, args.particles, 0.25, raster=False) for _, segs in scheds]
    check_work({k: args.seeds * sum(w[k] for w in work) for k in work[0]}, "--seeds/--particles/SCHEDULE.toml")
    from ..parallel import auto_workers, client_for, close_client

    cpu_s = args.seeds * sum(w["cpu_s"] for w in work)
    client = client_for(args.scheduler, auto_workers(args.seeds, cpu_s, args.workers, args.scheduler))
    try:
        results = [run_schedule_ensemble(card, name, segs, args.seeds, args.particles, args.seed, client=client)
                   for name, segs in scheds]
    finally:
        close_client(client)
    header, rows = table_rows(results)
    for res, (_, segs) in zip(results, scheds):  # the validity range, on the ensemble mean
        for line in simulation_warnings(card, segs, res.t_h, res.band("temperature_c")[0], res.band("s_mean_um")[0]):
            print(f"bmctl: warning: {res.name}: {line}", file=sys.stderr)
    print("ensemble mean [5-95 % over the plants] at each schedule's end; peak vial temperature: mean over the plants")
    w = max([28] + [len(r[0]) for r in rows])
    print(f"{'schedule':{w}s} {'h':>6s} {'kJ':>7s} {'peak °C':>7s} {'s_mean µm':>19s} {'s_std µm':>19s} "
          f"{'r_mean':>21s}")
    for r in rows:
        print(f"{r[0]:{w}s} {r[1]:6.4g} {r[2]:7.0f} {r[3]:7.1f} {r[5]:6.1f} [{r[6]:5.1f},{r[7]:5.1f}] "
              f"{r[8]:6.1f} [{r[9]:5.1f},{r[10]:5.1f}] {r[11]:6.3f} [{r[12]:.3f},{r[13]:.3f}]")
    for p in write_outputs(results, out):
        print(f"  wrote {p}")
    return 0
