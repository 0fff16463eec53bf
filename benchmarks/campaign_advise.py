"""Time `advise` on a campaign: the first call and warm calls, in one process and in fresh processes.

    python benchmarks/campaign_advise.py [--controller controllers/mpc-default.toml] [--repeat 3]
                                         [--compare OTHER_CHECKOUT]

Builds a 12 h campaign (MPC, d50 target) with ``repeat + 1`` logged and sampled intervals, then
runs ``bmctl campaign advise`` in fresh processes on copies of it. Prints wall time and CPU time
(user + system of the child; on a shared machine the CPU time is what an idle machine would take)
and the database size. ``--compare`` runs the same fresh-process advise from another checkout of
bmctl (e.g. ``git archive <commit> | tar -x -C /tmp/old``), alternating, for a before/after table.
"""

from __future__ import annotations

import argparse
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


def fresh_advise(src: Path, folder: Path) -> tuple[float, float, float]:
    """(wall s, child CPU s, advise_ms / 1e3) of one ``python -m bmctl campaign advise --json`` run from ``src``."""
    import json

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "bmctl", "campaign", "advise", str(folder), "--json"], cwd=src,
                         env={**os.environ, "PYTHONPATH": str(src)}, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, json.loads(out.stdout)["advise_ms"] / 1e3


def main() -> None:
    from bmctl import campaign as cp
    from bmctl.measure.tables import ParticleTable

    ap = argparse.ArgumentParser()
    ap.add_argument("--controller", default=str(ROOT / "controllers" / "mpc-default.toml"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--compare", default=None, help="another bmctl checkout to time side by side")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    d = tmp / "c"
    print(f"load: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    cp.init(d, ROOT / "models" / "alni-1to1-300rpm-lab.toml", a.controller, {"d50_um": 45.0}, hours=12.0)
    rng = np.random.default_rng(0)
    with cp.Campaign(d) as c:
        for k in range(a.repeat + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            adv = cp.advise(d, campaign=c)
            print(f"in-process advise {k}: {time.perf_counter() - t0:.2f} s wall, {time.process_time() - c0:.2f} s CPU "
                  f"(solve {adv['solve_ms'] / 1e3:.2f} s)")
            cp.log(d, adv["next"]["rpm"], 0.5, adv["next"]["mill_min"] / 30.0, campaign=c)
            cp.sample(d, c.clock_h(), [ParticleTable.from_size_aspect(rng.lognormal(np.log(50), 0.45, 300),
                                                                       rng.uniform(0, 0.1, 300))], campaign=c)
        cp.advise(d, campaign=c)  # the stored warm start for the fresh processes
    srcs = {"this": ROOT} | ({"compare": Path(a.compare).resolve()} if a.compare else {})
    for name, src in srcs.items():  # first run per checkout: fills its caches (gcc, model constants)
        shutil.copytree(d, tmp / f"warm-{name}")
        w, cpu, adv_s = fresh_advise(src, tmp / f"warm-{name}")
        print(f"fresh-process advise [{name}] first: {w:.2f} s wall, {cpu:.2f} s CPU (advise {adv_s:.2f} s)")
    res: dict[str, list] = {k: [] for k in srcs}
    for k in range(a.repeat):
        for name, src in srcs.items():
            f = tmp / f"{name}-{k}"
            shutil.copytree(d, f)
            res[name].append(fresh_advise(src, f))
            w, cpu, adv_s = res[name][-1]
            print(f"fresh-process advise [{name}] {k}: {w:.2f} s wall, {cpu:.2f} s CPU (advise {adv_s:.2f} s; "
                  f"CLI, imports included)")
    for name, r in res.items():
        m = np.median(np.array(r), axis=0)
        print(f"median fresh-process advise [{name}]: {m[0]:.2f} s wall, {m[1]:.2f} s CPU, advise {m[2]:.2f} s wall")
    print(f"load: {os.getloadavg()[0]:.1f}")
    print(f"database: {(d / 'campaign.sqlite').stat().st_size / 1e6:.2f} MB after {a.repeat + 1} intervals")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
