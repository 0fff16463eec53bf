"""Whole-process times of the main commands, this checkout against another one, side by side.

    python benchmarks/bench_fresh.py --compare OTHER_CHECKOUT [--repeat 2] [--only help,simulate,design,trial]

Each command runs as a fresh ``python -m bmctl ...`` process from each checkout (``PYTHONPATH`` and
the working folder set to it), alternating between the two, after one unmeasured warm-up run per
checkout and command (so compiled code is in the caches, as for every run after the first one on
a machine). Prints wall and CPU seconds (user + system of the child, its children included: gcc
started in the background is counted only if it finishes) and the ratio other / this per command.
Make the other checkout with ``git worktree add /tmp/before <commit>`` or ``git archive``.

Commands (the targets of docs/performance.md):

- help:     ``bmctl --help``
- simulate: ``bmctl simulate models/alni-1to1-300rpm-lab.toml --hours 12 --particles 20000`` (figures included)
- design:   ``bmctl design models/alni-1to1-300rpm-lab.toml --target s_mean_um=45``
- trial:    ``bmctl trial scenarios/trial-mismatch.toml`` (12 h, MPC with a particle filter)
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

ROOT = Path(__file__).resolve().parents[1]

COMMANDS = {
    "help": ["--help"],
    "simulate": ["simulate", "models/alni-1to1-300rpm-lab.toml", "--hours", "12", "--particles", "20000",
                 "--no-progress"],
    "design": ["design", "models/alni-1to1-300rpm-lab.toml", "--target", "s_mean_um=45"],
    "trial": ["trial", "scenarios/trial-mismatch.toml", "--no-progress"],
}


def run_once(src: Path, args: list[str], out: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one ``python -m bmctl ARGS [--out OUT]`` from checkout ``src``."""
    cmd = [sys.executable, "-m", "bmctl", *args] + ([] if args == ["--help"] else ["--out", str(out)])
    env = {**os.environ, "PYTHONPATH": str(src), "MPLBACKEND": "Agg"}
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=src, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare", required=True, help="the other bmctl checkout (e.g. before a change)")
    ap.add_argument("--repeat", type=int, default=2, help="measured runs per checkout and command")
    ap.add_argument("--only", default=",".join(COMMANDS), help="comma-separated subset of " + ", ".join(COMMANDS))
    a = ap.parse_args()
    names = [n for n in a.only.split(",") if n]
    bad = [n for n in names if n not in COMMANDS]
    if bad:
        sys.exit(f"--only: unknown command(s) {', '.join(bad)}")
    srcs = {"this": ROOT, "other": Path(a.compare).resolve()}
    tmp = Path(tempfile.mkdtemp(prefix="bench_fresh_"))
    print(f"load at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; other = {srcs['other']}")
    print(f"{'command':9s} {'this wall':>10s} {'this CPU':>9s} {'other wall':>11s} {'other CPU':>10s} "
          f"{'ratio (CPU)':>11s}")
    for name in names:
        for tag, src in srcs.items():  # warm-up: compiled caches filled as after a first run
            run_once(src, COMMANDS[name], tmp / f"{name}-{tag}-warm")
        res = {tag: [] for tag in srcs}
        for k in range(a.repeat):
            for tag, src in srcs.items():
                res[tag].append(run_once(src, COMMANDS[name], tmp / f"{name}-{tag}-{k}"))
        med = {tag: sorted(v)[len(v) // 2] for tag, v in res.items()}
        cpu = {tag: sorted(c for _, c in v)[len(v) // 2] for tag, v in res.items()}
        print(f"{name:9s} {med['this'][0]:9.2f}s {cpu['this']:8.2f}s {med['other'][0]:10.2f}s {cpu['other']:9.2f}s "
              f"{cpu['other'] / cpu['this']:10.2f}x", flush=True)
    print(f"load at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
