"""Whole-process times of the main commands, in fresh processes; optionally against another checkout.

    python benchmarks/bench_fresh.py [--repeat 2] [--only help,simulate,design,design-interpreted,trial]
    python benchmarks/bench_fresh.py --compare OTHER_CHECKOUT ...

Each command runs as a fresh ``python -m bmctl ...`` process (``PYTHONPATH`` and the working
folder set to the checkout) after one unmeasured warm-up run per command that fills the compiled
caches in the foreground (``BMCTL_COMPILE=now``, ``BMCTL_MPC_COMPILE=wait``), as for every run after
the first one on a machine. Prints the median wall and CPU seconds (user + system of the child,
its children included) and writes them with the load average to ``results/bench_fresh.json``
(``--no-results``: not). ``design-interpreted`` is ``design`` with compilation off
(``BMCTL_MPC_COMPILE=0``), run alternately with it: the compiled step's ratio side by side.
``--compare DIR`` also runs each command from another checkout, alternating with this one
(``git worktree add /tmp/before <commit>``), and prints the ratio other / this (CPU); it writes
``results/bench_fresh_compare.json``.

Commands (the targets of docs/performance.md):

- help:     ``bmctl --help``
- simulate: ``bmctl simulate models/alni-1to1-300rpm-lab.toml --hours 12 --particles 20000`` (figures included)
- design:   ``bmctl design models/alni-1to1-300rpm-lab.toml --target s_mean_um=45``
- trial:    ``bmctl trial scenarios/trial-mismatch.toml`` (12 h, ``mpc-default`` with a particle filter)
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

COMMANDS = {
    "help": ["--help"],
    "simulate": ["simulate", "models/alni-1to1-300rpm-lab.toml", "--hours", "12", "--particles", "20000",
                 "--no-progress"],
    "design": ["design", "models/alni-1to1-300rpm-lab.toml", "--target", "s_mean_um=45"],
    "trial": ["trial", "scenarios/trial-mismatch.toml", "--no-progress"],
}
COMMANDS["design-interpreted"] = COMMANDS["design"]
#: extra environment of a command's measured runs
ENV = {"design-interpreted": {"BMCTL_MPC_COMPILE": "0"}}
WARM = {"BMCTL_COMPILE": "now", "BMCTL_MPC_COMPILE": "wait"}


def run_once(src: Path, args: list[str], out: Path, extra: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s) of one ``python -m bmctl ARGS [--out OUT]`` from checkout ``src``."""
    cmd = [sys.executable, "-m", "bmctl", *args] + ([] if args == ["--help"] else ["--out", str(out)])
    env = {**os.environ, "PYTHONPATH": str(src), "MPLBACKEND": "Agg", **(extra or {})}
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=src, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", help="another bmctl checkout (e.g. before a change)")
    ap.add_argument("--repeat", type=int, default=2, help="measured runs per checkout and command")
    ap.add_argument("--only", default=",".join(COMMANDS), help="comma-separated subset of " + ", ".join(COMMANDS))
    ap.add_argument("--no-results", action="store_true", help="write no results file")
    a = ap.parse_args()
    names = [n for n in a.only.split(",") if n]
    bad = [n for n in names if n not in COMMANDS]
    if bad:
        sys.exit(f"--only: unknown command(s) {', '.join(bad)}")
    srcs = {"this": ROOT, **({"other": Path(a.compare).resolve()} if a.compare else {})}
    tmp = Path(tempfile.mkdtemp(prefix="bench_fresh_"))
    load0 = os.getloadavg()
    print(f"load at start: {load0[0]:.1f} on {os.cpu_count()} cores" + (f"; other = {srcs['other']}" if a.compare else ""))
    print(f"{'command':19s} {'this wall':>10s} {'this CPU':>9s}" +
          (f" {'other wall':>11s} {'other CPU':>10s} {'ratio (CPU)':>11s}" if a.compare else ""))
    record: dict = {"commands": {}}
    # design and design-interpreted alternate, so that their ratio is measured side by side
    groups = [[n] for n in names if n not in ("design", "design-interpreted")]
    pair = [n for n in ("design", "design-interpreted") if n in names]
    if pair:
        groups.insert(min(i for i, n in enumerate(names) if n in pair), pair)
    for group in groups:
        for name in group:
            for tag, src in srcs.items():  # warm-up: compiled caches filled in the foreground
                run_once(src, COMMANDS[name], tmp / f"{name}-{tag}-warm", WARM)
        res = {(name, tag): [] for name in group for tag in srcs}
        for k in range(a.repeat):
            for name in group:
                for tag, src in srcs.items():
                    res[name, tag].append(run_once(src, COMMANDS[name], tmp / f"{name}-{tag}-{k}", ENV.get(name)))
        for name in group:
            wall = {tag: float(np.median([w for w, _ in res[name, tag]])) for tag in srcs}
            cpu = {tag: float(np.median([c for _, c in res[name, tag]])) for tag in srcs}
            row = {"wall_s": wall["this"], "cpu_s": cpu["this"], "runs": res[name, "this"]}
            line = f"{name:19s} {wall['this']:9.2f}s {cpu['this']:8.2f}s"
            if a.compare:
                row.update(other_wall_s=wall["other"], other_cpu_s=cpu["other"], other_runs=res[name, "other"],
                           ratio_cpu=cpu["other"] / cpu["this"], ratio_wall=wall["other"] / wall["this"])
                line += f" {wall['other']:10.2f}s {cpu['other']:9.2f}s {cpu['other'] / cpu['this']:10.2f}x"
            record["commands"][name] = row
            print(line, flush=True)
    c = record["commands"]
    if "design" in c and "design-interpreted" in c:
        record["design_interpreted_ratio_cpu"] = c["design-interpreted"]["cpu_s"] / c["design"]["cpu_s"]
        record["design_interpreted_ratio_wall"] = c["design-interpreted"]["wall_s"] / c["design"]["wall_s"]
        print(f"design: interpreted / compiled step {record['design_interpreted_ratio_cpu']:.2f}x CPU, "
              f"{record['design_interpreted_ratio_wall']:.2f}x wall")
    print(f"load at end: {os.getloadavg()[0]:.1f}")
    if not a.no_results:
        sys.path.insert(0, str(ROOT))
        from bmctl.results import write_results

        record.update(load_average_start=list(load0), load_average_end=list(os.getloadavg()), cpus=os.cpu_count())
        settings = {"repeat": a.repeat, "commands": {n: " ".join(["bmctl", *COMMANDS[n]]) for n in names},
                    "env": {n: ENV[n] for n in names if n in ENV}, "compare": bool(a.compare)}
        extra = (f" --repeat {a.repeat}" if a.repeat != 2 else "") + \
            (f" --only {a.only}" if a.only != ",".join(COMMANDS) else "")
        write_results("bench_fresh_compare" if a.compare else "bench_fresh", record, settings=settings,
                      command="python benchmarks/bench_fresh.py" + (" --compare DIR" if a.compare else "") + extra)


if __name__ == "__main__":
    main()
