"""Speed of the measurement path: segmentation per image, and the micrograph sampler.

Run from the repository root::

    python benchmarks/bench_measure.py [--repeat 3] [--against DIR]

Prints one Markdown table (median wall time of ``--repeat`` runs, single process) and writes
``results/bench_measure.json`` (wall and CPU seconds, load average). With ``--against DIR``
(another checkout of bmctl, e.g. ``git worktree add --detach /tmp/base <commit>``) the same
cases run on that checkout's code in a subprocess, interleaved case by case with this one's,
and the table shows both and their ratio (this / that). Where DIR is a git checkout, the
recorded command begins with the ``git worktree add --detach DIR <commit>`` that makes it again.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"


def _time(fn, repeat: int) -> tuple[float, float]:
    wall, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def cases():
    """(name, function) of every case, in order."""
    from bmctl.measure import load_image, measure_image, micrograph_sample, render_micrograph
    from bmctl.measure.micrograph import measure_micrograph

    out = []
    syn = render_micrograph(np.random.default_rng(0), n=200, shape=(1024, 1024), s_px=(15, 60))
    out.append(("segment + measure, synthetic 1024x1024, 200 particles", lambda: measure_image(syn.image, 1.0)))
    png = DATA / "ampis_powder_b.png"
    if png.exists():
        img = load_image(png)
        out.append(("segment + measure, AMPIS powder 1536x1024 (~240 particles)", lambda: measure_image(img, 1.0)))
    tif = DATA / "sio2_sem_12000x.tif"
    if tif.exists():
        img2 = load_image(tif)
        out.append(("segment + measure, SiO2 712x423 cropped (~500 particles)", lambda: measure_image(img2, 0.0368, crop="0:423,:")))
        out.append(("measure_micrograph, SiO2 712x484 (scale from metadata, data bar found, checks)", lambda: measure_micrograph(tif)))
    rng = np.random.default_rng(1)
    s = rng.lognormal(np.log(40.0), 0.4, 10000)
    r = np.clip(rng.gamma(2.0, 0.03, 10000), 0, 0.6)
    out.append(("micrograph_sample fast path, n = 1000", lambda: micrograph_sample(s, r, 1000, rng, um_per_px=1.0)))
    out.append(("micrograph_sample render path, n = 200", lambda: micrograph_sample(s, r, 200, rng, um_per_px=2.0, render=True)))
    return out


def _checkout_commit(folder: Path) -> str | None:
    """The short commit a git checkout at ``folder`` is on, or None where it is not one."""
    try:
        out = subprocess.run(["git", "-C", str(folder), "rev-parse", "--short=7", "HEAD"],
                             capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip() or None


def _one(index: int, repeat: int) -> None:
    """Subprocess mode: time case ``index`` and print JSON."""
    name, fn = cases()[index]
    wall, cpu = _time(fn, repeat)
    print(json.dumps({"name": name, "wall_s": wall, "cpu_s": cpu}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--against", type=Path, default=None, metavar="DIR", help="another bmctl checkout to time side by side")
    ap.add_argument("--case", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case is not None:
        _one(args.case, args.repeat)
        return 0
    sys.path.insert(0, str(ROOT))
    load = os.getloadavg()
    rows = []
    for k, (name, fn) in enumerate(cases()):
        wall, cpu = _time(fn, args.repeat)
        row = {"name": name, "wall_s": wall, "cpu_s": cpu}
        if args.against is not None:
            env = dict(os.environ, PYTHONPATH=str(args.against.resolve()), MPLBACKEND="Agg")
            out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--case", str(k), "--repeat", str(args.repeat)],
                                 capture_output=True, text=True, env=env, cwd=str(args.against), check=True)
            other = json.loads(out.stdout.strip().splitlines()[-1])
            row.update(against_wall_s=other["wall_s"], against_cpu_s=other["cpu_s"], ratio=wall / other["wall_s"])
        rows.append(row)
    if args.against is None:
        print("| case | median s |\n|---|---|")
        for r in rows:
            print(f"| {r['name']} | {r['wall_s']:.3g} |")
    else:
        print(f"| case | this (s) | {args.against} (s) | ratio |\n|---|---|---|---|")
        for r in rows:
            print(f"| {r['name']} | {r['wall_s']:.3g} | {r['against_wall_s']:.3g} | {r['ratio']:.2f} |")
    from bmctl.results import write_results

    cmd = "python benchmarks/bench_measure.py" + (f" --repeat {args.repeat}" if args.repeat != 3 else "") + (
        f" --against {args.against}" if args.against is not None else "")
    commit = _checkout_commit(args.against) if args.against is not None else None
    if commit is not None:
        # the baseline folder is gone after the run: record how to make it again
        cmd = f"git worktree add --detach {args.against} {commit} && {cmd}"
    path = write_results("bench_measure", {"cases": rows, "loadavg_start": list(load), "loadavg_end": list(os.getloadavg())},
                         settings={"repeat": args.repeat, "against": str(args.against) if args.against else None}, command=cmd)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
