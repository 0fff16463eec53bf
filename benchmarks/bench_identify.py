"""`bmctl identify` on a new card: whole-command wall and CPU seconds, and its held-out accuracy on a fresh set.

    python benchmarks/bench_identify.py [--card lab-15mm] [--repeat 1] [--workers 2] [--compare OTHER_CHECKOUT]

The new card is the lab card with 15 mm balls and the mass they derive (``impactor_mass_kg`` left out:
rho pi d^3 / 6 = 13.96 g), written to a temporary folder: no identified coefficients exist for it, so
``bmctl identify`` starts from the nearest identified card (the shipped lab card). The command runs as a
fresh process (``python -m bmctl identify CARD``), timed: wall and CPU seconds (user + system of it and
its Dask workers), with ``os.getloadavg()`` before and after (the machine may be shared: a load above the
core count inflates the wall time, not the CPU time). ``--compare`` times another checkout's
``bmctl identify CARD --quick`` the same way, side by side (the ratio is printed).

Accuracy is scored on a set identification never sees: 24 random schedules from stream 3 (the one
``benchmarks/moments_confirm.py`` uses), plant seeds 21-23, M = 4000 (``identify.nrmse_table``): mean
NRMSE per moment over the schedules, and the worst of the four moments (the issue's "worst held-out
NRMSE"). Writes ``results/bench_identify.json``.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CARDS = {"lab-15mm": (("ball_diameter_m = 0.010", "ball_diameter_m = 0.015"),)}


def new_card(name: str, folder: Path) -> Path:
    """The lab card with ``CARDS[name]``'s replacements, its ball mass left to be derived, renamed ``name``."""
    text = LAB.read_text().replace('name = "alni-1to1-300rpm-lab"', f'name = "{name}"')
    for old, new in CARDS[name]:
        assert old in text, old
        text = text.replace(old, new)
    text = re.sub(r"impactor_mass_kg = .*\n", "", text)
    p = folder / f"{name}.toml"
    p.write_text(text)
    return p


def timed(src: Path, args: list[str], log: Path) -> dict:
    """Wall and CPU seconds of ``python -m bmctl ARGS`` from checkout ``src`` (children included)."""
    env = {**os.environ, "PYTHONPATH": str(src), "MPLBACKEND": "Agg"}
    load0 = os.getloadavg()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        subprocess.run([sys.executable, "-m", "bmctl", *args], cwd=src, env=env, check=True, stdout=f,
                       stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "load_before": [round(v, 2) for v in load0],
            "load_after": [round(v, 2) for v in os.getloadavg()]}


def score(card_path: Path, coeffs: Path, schedules: int, seeds: list[int], particles: int) -> dict:
    """Mean NRMSE per moment over a fresh held-out set (stream 3), and the worst moment."""
    import numpy as np

    from bmctl.config import load_card
    from bmctl.moments import identify as ident
    from bmctl.moments.model import make_moment_model

    card = load_card(card_path)
    runs = ident.run_experiments(card, ident.validation_design(card, 0, schedules, stream=3), seeds, particles)
    tab = ident.nrmse_table(make_moment_model(card, coeffs), runs)
    names = ident.MOMENTS[:4]
    mean = {k: round(100 * float(v), 2) for k, v in zip(names, tab["mean"][:4])}
    worst = max(mean, key=mean.get)
    return {"mean_pct": mean, "worst_moment": worst, "worst_pct": mean[worst],
            "max_schedule_pct": {k: round(100 * float(v), 2) for k, v in zip(names, tab["max"][:4])},
            "defaults_worst_pct": round(100 * float(np.max(ident.nrmse_table(
                make_moment_model(card, {}), runs)["mean"][:4])), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--card", default="lab-15mm", choices=sorted(CARDS))
    ap.add_argument("--repeat", type=int, default=1, help="timed identify runs (the last one is scored)")
    ap.add_argument("--workers", default=None, help="passed to identify --workers (default: its own choice)")
    ap.add_argument("--compare", default=None, help="another checkout: its `bmctl identify CARD --quick`, timed alike")
    ap.add_argument("--no-results", action="store_true", help="print only; do not write results/bench_identify.json")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-identify-"))
    card = new_card(a.card, tmp)
    out = tmp / f"{a.card}.moments.toml"
    args = ["identify", str(card), "--out", str(out)] + (["--workers", a.workers] if a.workers else [])
    runs = []
    for k in range(a.repeat):
        runs.append(timed(ROOT, args, tmp / f"identify-{k}.log"))
        print(f"identify {a.card}: {runs[-1]['wall_s']:.1f} s wall, {runs[-1]['cpu_s']:.1f} s CPU, "
              f"load {runs[-1]['load_before'][0]:.2f} -> {runs[-1]['load_after'][0]:.2f}", flush=True)
    values = {"runs": runs, "wall_s": min(r["wall_s"] for r in runs), "cpu_s": min(r["cpu_s"] for r in runs),
              "cores": len(os.sched_getaffinity(0))}
    from bmctl.moments import coeffs as cf

    f = cf.read_file(out)
    values["identify"] = {k: f.identification.get(k) for k in ("start", "evaluations", "jacobians", "plant_seconds",
                                                                "fit_seconds", "experiments", "particles")}
    values["identify_heldout_pct"] = {k: round(100 * float(v), 2) for k, v in f.heldout_mean.items()}
    values["fresh_heldout"] = score(card, out, 24, [21, 22, 23], 4000)
    print(f"fresh held-out NRMSE (24 schedules, stream 3, seeds 21-23, M=4000): "
          + ", ".join(f"{k} {v:.2f} %" for k, v in values["fresh_heldout"]["mean_pct"].items())
          + f"; worst {values['fresh_heldout']['worst_pct']:.2f} % ({values['fresh_heldout']['worst_moment']})")
    if a.compare:
        other = Path(a.compare).resolve()
        o = timed(other, ["identify", str(card), "--quick", "--out", str(tmp / "other.moments.toml")],
                  tmp / "other.log")
        values["compare"] = {"checkout": str(other), "command": "bmctl identify CARD --quick", **o,
                             "ratio_wall": round(o["wall_s"] / values["wall_s"], 2),
                             "ratio_cpu": round(o["cpu_s"] / values["cpu_s"], 2)}
        print(f"other checkout --quick: {o['wall_s']:.1f} s wall, {o['cpu_s']:.1f} s CPU; ratio other / this "
              f"{values['compare']['ratio_wall']:.2f} wall, {values['compare']['ratio_cpu']:.2f} CPU")
    if not a.no_results:
        from bmctl.results import write_results

        cmd = "python benchmarks/bench_identify.py" + "".join(
            f" {k} {v}" for k, v in (("--card", a.card if a.card != "lab-15mm" else None),
                                     ("--repeat", a.repeat if a.repeat != 1 else None),
                                     ("--workers", a.workers), ("--compare", a.compare)) if v is not None)
        settings = {"card": a.card, "card_change": [list(x) for x in CARDS[a.card]],
                    "identify_args": [x.replace(str(tmp), "TMP") for x in args[2:]],  # TMP: its temporary folder
                    "fresh_set": {"schedules": 24, "stream": 3, "seeds": [21, 22, 23], "particles": 4000}}
        print(f"wrote {write_results('bench_identify', values, settings=settings, command=cmd)}")


if __name__ == "__main__":
    main()
