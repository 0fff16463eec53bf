"""`bmctl design` on the laboratory card: a reachable target, an unreachable one and a shortest batch,
each with the plant check.

    nice python benchmarks/design_reach.py

Cases (12 h, ``controllers/mpc-default.toml``, 80 °C ceiling, 5 min dwell limits, 36 switches):

* ``s_mean_um=30``: reachable (300 rpm, then 330 rpm); the global search against the local NLP
  started from the search's best schedules (and the card's rpm), and the plant's result (3 plants,
  5000 particles, seed 0);
* ``s_mean_um=400``: out of reach (milling makes the powder no coarser than the welding hump's
  peak): the closest schedule, the binding limits, the best row per family (plant check: 1 plant);
* ``d50_um=55:65 --objective min_time``: the shortest of 3, 6, 9, 12 h that ends in the window
  (plant check: 1 plant).

Writes ``results/design_reach.json`` (``bmctl.results``) with the search's and the local NLP's
errors, the plant check, the search's size and its CPU time (``os.getloadavg()`` beside it).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CONTROLLER = ROOT / "controllers" / "mpc-default.toml"
CASES = (("reachable", {"s_mean_um": 30.0}, "target", 3),
         ("unreachable", {"s_mean_um": 400.0}, "target", 1),
         ("min_time", {"d50_um": (55.0, 65.0)}, "min_time", 1))


def main(argv=None) -> None:
    import argparse

    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)  # no options: --help, or refused
    from bmctl.control.config import load_controller
    from bmctl.control.design import design_schedule, plant_check, switches_of
    from bmctl.moments import for_card
    from bmctl.results import write_results

    model = for_card(CARD)
    cfg = load_controller(CONTROLLER)
    out = {"load_before": list(os.getloadavg())}
    for name, target, objective, seeds in CASES:
        t0, c0 = time.perf_counter(), time.process_time()
        d = design_schedule(model, target, 12.0, cfg, objective=objective)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        pc = plant_check(model.card, d.segments, target, seeds, 5000, 0)
        key = next(iter(target))
        r = d.result
        row = {"target": {k: list(v) if isinstance(v, tuple) else v for k, v in target.items()},
               "objective": objective, "hours": d.hours, "reachable": d.reach.reachable,
               "error_pct": 100 * r.error, "predicted": r.outputs[key], "method": r.method,
               "search_error_pct": 100 * d.searched.error, "search_family": d.searched.family,
               "search_schedules": d.search.evaluated,
               "local_error_pct": None if d.local is None else 100 * d.local.error,
               "peak_c": r.peak_c, "switches": d.switches, "milling_h": r.milling_h, "energy_kWh": r.energy_kWh,
               "segments": [[h, rpm] for h, rpm in d.segments], "binding": d.reach.binding,
               "per_family": {f: {k: v for k, v in fam.items() if k != "params"}
                              for f, fam in d.reach.per_family.items()},
               "plant": pc, "plant_error_pct": None, "design_wall_s": wall, "design_cpu_s": cpu}
        if isinstance(target[key], float):
            row["plant_error_pct"] = 100 * (pc[key]["mean"] - target[key]) / target[key]
        if d.pareto:
            row["pareto"] = [{"hours": p.hours, "milling_h": p.milling_h, "energy_kWh": p.energy_kWh,
                              "error_pct": 100 * p.error, "switches": switches_of(p), "peak_c": p.peak_c} for p in d.pareto]
        out[name] = row
        print(f"{name}: {target} -> {key} {r.outputs[key]:.4g} (error {100 * r.error:.2f} %, {r.method}); search "
              f"{100 * d.searched.error:.2f} % ({d.searched.family}), local NLP "
              f"{'-' if d.local is None else f'{100 * d.local.error:.2f} %'}; plant {pc[key]['mean']:.4g} "
              f"[{pc[key]['min']:.4g}, {pc[key]['max']:.4g}]; peak {r.peak_c:.1f} °C; {cpu:.1f} s CPU", flush=True)
        if not d.reach.reachable:
            print("  " + d.reach.line(target))
            print("\n".join(d.reach.family_lines()))
    out["load_after"] = list(os.getloadavg())
    path = write_results("design_reach", out, settings={"card": str(CARD.relative_to(ROOT)),
                                                       "controller": str(CONTROLLER.relative_to(ROOT)),
                                                       "hours": 12.0, "plant_particles": 5000, "seed": 0},
                         command="python benchmarks/design_reach.py")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
