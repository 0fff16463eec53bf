"""Time `bmctl campaign advise` in fresh processes: the first advice of a fresh campaign (with empty
caches, and with the caches another campaign left) and later ones.

    nice python benchmarks/campaign_advise.py [--controller controllers/mpc-default.toml] [--repeat 6]

A 12 h campaign on the laboratory card (target s_mean_um = 32). *First*: ``campaign init`` then
``campaign advise --json`` in a new process, once with an empty cache folder (``XDG_CACHE_HOME``:
nothing compiled, no model constants cached) and once more on a second fresh campaign with the cache
the first left. *Later*: the advice is logged and a 300-particle sample added every interval, then
``advise`` runs again in a new process, ``--repeat`` times. Prints wall and CPU seconds (user +
system of the child) with the load average, and the ratios to the targets (first <= 10 s, later
<= 2 s wall on two cores); writes ``results/campaign_advise.json`` (``bmctl.results``). On a shared
machine the CPU seconds are what an idle one would take.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
FIRST_TARGET_S, LATER_TARGET_S = 10.0, 2.0


def run(args, env) -> tuple[str, float, float]:
    """(stdout, wall s, child CPU s) of ``python -m bmctl ARGS``."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "bmctl", *args], cwd=ROOT, env=env, check=True, capture_output=True,
                         text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return out.stdout, wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    from bmctl.measure.tables import ParticleTable, write_table
    from bmctl.results import write_results

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--controller", default=str(ROOT / "controllers" / "mpc-default.toml"))
    ap.add_argument("--repeat", type=int, default=6, help="later advices timed")
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bmctl-advise-"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_CACHE_HOME": str(tmp / "cache"), "MPLBACKEND": "Agg"}
    env.pop("BMCTL_MPC_COMPILE", None)
    load0 = os.getloadavg()
    print(f"load: {load0[0]:.1f} on {os.cpu_count()} cores")
    init = ["--model", str(CARD), "--controller", a.controller, "--target", "s_mean_um=32", "--hours", "12"]
    first = {}
    for name in ("empty cache", "cache of another campaign"):
        d = tmp / name.replace(" ", "-")
        run(["campaign", "init", str(d), *init], env)
        out, wall, cpu = run(["campaign", "advise", str(d), "--json"], env)
        first[name] = {"wall_s": wall, "cpu_s": cpu, "advise_ms": json.loads(out)["advise_ms"]}
        print(f"first advise ({name}): {wall:.2f} s wall, {cpu:.2f} s CPU", flush=True)
    rng = np.random.default_rng(0)
    later = []
    for k in range(a.repeat):
        adv = json.loads(out)
        nx = adv["next"]
        run(["campaign", "decide", str(d), "--accept"], env)
        run(["campaign", "log", str(d), "--rpm", f"{nx['rpm']:g}", "--hours", "0.5", "--milling",
             f"{nx['mill_min'] / 30.0:.10g}", "--temperature-c", f"{40 + 5 * k:g}"], env)
        tab = tmp / f"s{k}.csv"
        write_table(tab, ParticleTable.from_size_aspect(rng.lognormal(np.log(48 - 2 * k), 0.45, 300),
                                                         rng.uniform(0, 0.1, 300)))
        run(["campaign", "sample", str(d), "--at-h", f"{0.5 * (k + 1):g}", str(tab)], env)
        out, wall, cpu = run(["campaign", "advise", str(d), "--json"], env)
        later.append({"t_h": 0.5 * (k + 1), "wall_s": wall, "cpu_s": cpu, "advise_ms": json.loads(out)["advise_ms"],
                      "solver": json.loads(out)["solver"]})
        print(f"later advise at {0.5 * (k + 1):g} h: {wall:.2f} s wall, {cpu:.2f} s CPU "
              f"({json.loads(out)['solver'][:60]})", flush=True)
    lw = float(np.median([r["wall_s"] for r in later]))
    lc = float(np.median([r["cpu_s"] for r in later]))
    fw = max(v["wall_s"] for v in first.values())
    fc = max(v["cpu_s"] for v in first.values())
    load1 = os.getloadavg()
    print(f"first advise: at most {fw:.2f} s wall, {fc:.2f} s CPU ({fc / FIRST_TARGET_S:.2f} x the {FIRST_TARGET_S:g} s "
          f"target in CPU); later: median {lw:.2f} s wall, {lc:.2f} s CPU ({lc / LATER_TARGET_S:.2f} x the "
          f"{LATER_TARGET_S:g} s target in CPU); load {load0[0]:.1f} -> {load1[0]:.1f}")
    shutil.rmtree(tmp, ignore_errors=True)
    if not a.no_results:
        path = write_results("campaign_advise", {
            "first": first, "later": later, "first_wall_s": fw, "first_cpu_s": fc, "later_median_wall_s": lw,
            "later_median_cpu_s": lc, "load_before": list(load0), "load_after": list(load1),
            "cpus": os.cpu_count()}, settings={"controller": os.path.relpath(a.controller, ROOT), "repeat": a.repeat,
                                               "card": str(CARD.relative_to(ROOT)), "hours": 12.0,
                                               "target": {"s_mean_um": 32.0}},
            command="python benchmarks/campaign_advise.py")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
