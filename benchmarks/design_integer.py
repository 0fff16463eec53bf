"""Integer decisions of `bmctl design`: relax-and-round with a re-solve against casadi's Bonmin.

Run:  nice python benchmarks/design_integer.py [--target s_mean_um=30] [--hours 12]
          [--card models/alni-1to1-300rpm-lab.toml] [--controller controllers/mpc-default.toml]

Prints, per method, the wall time, the objective, the final error of the simulated rounded
schedule, its on/off switches and the limits active at the solution.
"""

from __future__ import annotations

import argparse
import time

from bmctl.control import load_controller
from bmctl.control.config import parse_target
from bmctl.control.pattern import PatternDesigner
from bmctl.moments.model import make_moment_model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", default="s_mean_um=30")
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--card", default="models/alni-1to1-300rpm-lab.toml")
    ap.add_argument("--controller", default="controllers/mpc-default.toml")
    ap.add_argument("--methods", default="relax-round,bonmin")
    a = ap.parse_args()
    model = make_moment_model(a.card)
    cfg = load_controller(a.controller)
    t0 = time.perf_counter()
    d = PatternDesigner(model, a.hours, cfg, parse_target(a.target))
    print(f"build {time.perf_counter() - t0:.1f} s")
    print("| method | solve s | cost | final error % | switches | rpm per phase | active limits |")
    print("|---|---|---|---|---|---|---|")
    for meth in a.methods.split(","):
        r = d.solve(meth)
        print(f"| {meth} | {r.solve_s:.0f} | {r.cost:.5g} | {100 * r.error:.1f} | {r.switches} | "
              f"{', '.join(f'{v:.0f}' for v in r.rpm)} | {', '.join(r.active)} |", flush=True)


if __name__ == "__main__":
    main()
